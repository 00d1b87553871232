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
// PKI_DIR is node-opcua's own PKI, as for read.mjs.
import { OPCUACertificateManager } from "node-opcua-certificate-manager";
import {
  AttributeIds,
  MessageSecurityMode,
  OPCUAClient,
  ObjectTypeIds,
  SecurityPolicy,
  TimestampsToReturn,
  UserTokenType,
  callConditionRefresh,
  constructEventFilter,
  ofType,
  resolveNodeId,
} from "node-opcua-client";

const [endpoint, pkiDir, userName, conditionName] = process.argv.slice(2);
const password = process.env.TANKLAB_PASSWORD;
if (!endpoint || !pkiDir || !userName || !conditionName || !password) {
  process.stderr.write("usage: TANKLAB_PASSWORD=... node alarms.mjs ENDPOINT PKI_DIR USER CONDITION_NAME\n");
  process.exit(2);
}

const FIELDS = ["EventId", "EventType", "ConditionName", "AckedState.Id", "Comment", "ConditionId"];
const REFRESH_START = resolveNodeId(ObjectTypeIds.RefreshStartEventType).toString();
const REFRESH_END = resolveNodeId(ObjectTypeIds.RefreshEndEventType).toString();

const certificateManager = new OPCUACertificateManager({
  rootFolder: pkiDir,
  automaticallyAcceptUnknownCertificate: false,
});
const client = OPCUAClient.create({
  applicationName: "tanklab node-opcua alarm client",
  applicationUri: "urn:tanklab:test:node-opcua",
  securityMode: MessageSecurityMode.SignAndEncrypt,
  securityPolicy: SecurityPolicy.Basic256Sha256,
  clientCertificateManager: certificateManager,
  endpointMustExist: false,
  connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
  requestedSessionTimeout: 10000,
});

function report(result, code) {
  process.stdout.write(`RESULT ${JSON.stringify({ ...result, certificate: client.certificateFile })}\n`);
  process.exitCode = code;
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
        { queueSize: 100, filter, discardOldest: false },
        TimestampsToReturn.Both,
      );
      item.on("changed", (values) => {
        const ev = {};
        FIELDS.forEach((name, i) => (ev[name] = values[i].value));
        queue.items.push(ev);
        if (queue.waiter) queue.waiter();
      });
      const refreshed = await callConditionRefresh(session, subscription.subscriptionId);
      if (!refreshed.isGood()) throw new Error(`ConditionRefresh: ${refreshed.name}`);
      await next(queue, (ev) => ev.EventType.toString() === REFRESH_START, 5000, "RefreshStart");
      const names = [];
      let target = null;
      await next(
        queue,
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
        const after = await next(queue, (ev) => ev.ConditionName === conditionName, 5000, "the acknowledged event");
        acked = after["AckedState.Id"];
      }
      report(
        {
          ok: status.isGood() && acked === true,
          refresh: names,
          eventId: target.EventId.toString("hex"),
          conditionId: target.ConditionId.toString(),
          ack: status.name,
          acked,
        },
        status.isGood() && acked === true ? 0 : 1,
      );
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
