// A node-opcua client that watches a live tanklab alarm through a real PLC (issue #15): it
// subscribes to events on the Server object with a Part 9 field list (OfType AlarmConditionType),
// says READY once the monitored item exists, waits for the condition CONDITION_NAME to become
// active (the test drives the process there), acknowledges that event with node-opcua's
// acknowledgeCondition (the event's ConditionId and EventId) and waits for the acknowledged event.
// Lines on stdout:
//   READY
//   RESULT {"ok": true, "active": {<fields of the activation event>}, "ack": "<StatusCode name>",
//           "acked": {<fields of the acknowledged event>}, "certificate": "..."}
//   RESULT {"ok": false, "error": "<message>", "certificate": "..."}
// Field values are JSON: NodeIds and LocalizedTexts as text, EventIds in hex. Exit code 0 when it
// acknowledged and saw the acknowledged event, 1 otherwise, 2 on bad usage.
//
//   node live_alarm.mjs ENDPOINT PKI_DIR USER CONDITION_NAME WAIT_MS   (password in $TANKLAB_PASSWORD)
//
// WAIT_MS bounds the wait for the activation (a hang, not a speed check). PKI_DIR is node-opcua's
// own PKI (session.mjs says its layout).
import { alarmEvents, main } from "./session.mjs";

const FIELDS = [
  "EventId",
  "EventType",
  "SourceName",
  "ConditionName",
  "Severity",
  "Message",
  "Retain",
  "ActiveState.Id",
  "AckedState.Id",
  "Comment",
  "ClientUserId",
  "ConditionId",
];

/** A field value as JSON. */
function plain(value) {
  if (value === null || value === undefined) return null;
  if (Buffer.isBuffer(value)) return value.toString("hex");
  if (typeof value === "object" && "text" in value) return value.text;
  if (typeof value === "object") return value.toString();
  return value;
}

function shown(ev) {
  const out = {};
  for (const name of FIELDS) out[name] = plain(ev[name]);
  return out;
}

await main(
  "live_alarm.mjs",
  ["ENDPOINT", "PKI_DIR", "USER", "CONDITION_NAME", "WAIT_MS"],
  async (session, args) => {
    const events = await alarmEvents(session, FIELDS, 1000);
    process.stdout.write("READY\n");
    const mine = (ev) => ev.ConditionName === args.CONDITION_NAME;
    const active = await events.next(
      (ev) => mine(ev) && ev["ActiveState.Id"] === true,
      Number(args.WAIT_MS),
      `${args.CONDITION_NAME} active`,
    );
    const status = await session.acknowledgeCondition(active.ConditionId, active.EventId, "from node-opcua");
    let acked = null;
    if (status.isGood()) {
      acked = await events.next((ev) => mine(ev) && ev["AckedState.Id"] === true, 20000, "the acknowledged event");
    }
    return {
      result: { active: shown(active), ack: status.name, acked: acked && shown(acked) },
      ok: status.isGood() && acked !== null,
    };
  },
  { sessionTimeoutMs: 20000 },
);
