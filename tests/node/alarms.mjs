// A node-opcua client that works a tanklab alarm the way an A&C client does (issue #15): it
// subscribes to events on the Server object with OfType AlarmConditionType, calls
// ConditionRefresh, takes the condition CONDITION_NAME from the refresh, acknowledges it with
// node-opcua's acknowledgeCondition (the condition's ConditionId and the event's EventId), and
// waits for the acknowledged event. One result line on stdout:
//   RESULT {"ok": true, "refresh": [<ConditionNames between RefreshStart and RefreshEnd>],
//           "eventId": "<hex>", "conditionId": "<NodeId>", "ack": "<StatusCode name>",
//           "acked": <AckedState/Id of the next event>, "certificate": "..."}
//   RESULT {"ok": false, "error": "<message>", "certificate": "..."}
// Exit code 0 when it acknowledged and saw the acknowledged event, 1 otherwise, 2 on bad usage.
//
//   node alarms.mjs ENDPOINT PKI_DIR USER CONDITION_NAME        (password in $TANKLAB_PASSWORD)
//
// PKI_DIR is node-opcua's own PKI (session.mjs says its layout).
import { ObjectTypeIds, callConditionRefresh, resolveNodeId } from "node-opcua-client";
import { alarmEvents, main } from "./session.mjs";

const FIELDS = ["EventId", "EventType", "ConditionName", "AckedState.Id", "Comment", "ConditionId"];
const REFRESH_START = resolveNodeId(ObjectTypeIds.RefreshStartEventType).toString();
const REFRESH_END = resolveNodeId(ObjectTypeIds.RefreshEndEventType).toString();

await main("alarms.mjs", ["ENDPOINT", "PKI_DIR", "USER", "CONDITION_NAME"], async (session, args) => {
  const conditionName = args.CONDITION_NAME;
  const events = await alarmEvents(session, FIELDS, 100);
  const refreshed = await callConditionRefresh(session, events.subscription.subscriptionId);
  if (!refreshed.isGood()) throw new Error(`ConditionRefresh: ${refreshed.name}`);
  await events.next((ev) => ev.EventType.toString() === REFRESH_START, 5000, "RefreshStart");
  const names = [];
  let target = null;
  await events.next(
    (ev) => {
      if (ev.EventType.toString() === REFRESH_END) return true;
      names.push(ev.ConditionName);
      if (ev.ConditionName === conditionName) target = ev;
      return false;
    },
    5000,
    "RefreshEnd",
  );
  if (!target) throw new Error(`${conditionName} not among the refreshed conditions ${JSON.stringify(names)}`);
  const status = await session.acknowledgeCondition(target.ConditionId, target.EventId, "from node-opcua");
  let acked = null;
  if (status.isGood()) {
    const after = await events.next((ev) => ev.ConditionName === conditionName, 5000, "the acknowledged event");
    acked = after["AckedState.Id"];
  }
  return {
    result: {
      refresh: names,
      eventId: target.EventId.toString("hex"),
      conditionId: target.ConditionId.toString(),
      ack: status.name,
      acked,
    },
    ok: status.isGood() && acked === true,
  };
});
