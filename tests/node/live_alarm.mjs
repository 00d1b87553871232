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
// own PKI, as for read.mjs.
import { OPCUACertificateManager } from "node-opcua-certificate-manager";
import {
  AttributeIds,
  MessageSecurityMode,
  OPCUAClient,
  SecurityPolicy,
  TimestampsToReturn,
  UserTokenType,
  constructEventFilter,
  ofType,
} from "node-opcua-client";

const [endpoint, pkiDir, userName, conditionName, waitMs] = process.argv.slice(2);
const password = process.env.TANKLAB_PASSWORD;
if (!endpoint || !pkiDir || !userName || !conditionName || !waitMs || !password) {
  process.stderr.write(
    "usage: TANKLAB_PASSWORD=... node live_alarm.mjs ENDPOINT PKI_DIR USER CONDITION_NAME WAIT_MS\n",
  );
  process.exit(2);
}

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

const certificateManager = new OPCUACertificateManager({
  rootFolder: pkiDir,
  automaticallyAcceptUnknownCertificate: false,
});
const client = OPCUAClient.create({
  applicationName: "tanklab node-opcua live alarm client",
  applicationUri: "urn:tanklab:test:node-opcua",
  securityMode: MessageSecurityMode.SignAndEncrypt,
  securityPolicy: SecurityPolicy.Basic256Sha256,
  clientCertificateManager: certificateManager,
  endpointMustExist: false,
  connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
  requestedSessionTimeout: 20000,
});

function report(result, code) {
  process.stdout.write(`RESULT ${JSON.stringify({ ...result, certificate: client.certificateFile })}\n`);
  process.exitCode = code;
}

/** A field value as JSON. */
function plain(value) {
  if (value === null || value === undefined) return null;
  if (Buffer.isBuffer(value)) return value.toString("hex");
  if (typeof value === "object" && "text" in value) return value.text;
  if (typeof value === "object") return value.toString();
  return value;
}

/** The next event that `accept` takes, or an error after `ms` milliseconds. */
function next(queue, accept, ms, what) {
  return new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error(`timed out waiting for ${what}`)), ms);
    const look = () => {
      while (queue.items.length) {
        const ev = queue.items.shift();
        if (accept(ev)) {
          clearTimeout(timer);
          queue.waiter = null;
          resolve(ev);
          return;
        }
      }
      queue.waiter = look;
    };
    look();
  });
}

function shown(ev) {
  const out = {};
  for (const name of FIELDS) out[name] = plain(ev[name]);
  return out;
}

try {
  await client.connect(endpoint);
  try {
    const session = await client.createSession({ type: UserTokenType.UserName, userName, password });
    try {
      const subscription = await session.createSubscription2({
        requestedPublishingInterval: 100,
        requestedLifetimeCount: 600,
        requestedMaxKeepAliveCount: 20,
        publishingEnabled: true,
      });
      const queue = { items: [], waiter: null };
      const filter = constructEventFilter(FIELDS, ofType("AlarmConditionType"));
      const item = await subscription.monitor(
        { nodeId: "i=2253", attributeId: AttributeIds.EventNotifier },
        { queueSize: 1000, filter, discardOldest: false },
        TimestampsToReturn.Both,
      );
      item.on("changed", (values) => {
        const ev = {};
        FIELDS.forEach((name, i) => (ev[name] = values[i].value));
        queue.items.push(ev);
        if (queue.waiter) queue.waiter();
      });
      process.stdout.write("READY\n");
      const mine = (ev) => ev.ConditionName === conditionName;
      const active = await next(
        queue,
        (ev) => mine(ev) && ev["ActiveState.Id"] === true,
        Number(waitMs),
        `${conditionName} active`,
      );
      const status = await session.acknowledgeCondition(active.ConditionId, active.EventId, "from node-opcua");
      let acked = null;
      if (status.isGood()) {
        acked = await next(queue, (ev) => mine(ev) && ev["AckedState.Id"] === true, 20000, "the acknowledged event");
      }
      const ok = status.isGood() && acked !== null;
      report({ ok, active: shown(active), ack: status.name, acked: acked && shown(acked) }, ok ? 0 : 1);
    } finally {
      await session.close();
    }
  } finally {
    await client.disconnect();
  }
} catch (err) {
  report({ ok: false, error: String(err && err.message ? err.message : err) }, 1);
  await client.disconnect().catch(() => {});
}
