// A node-opcua client reading history the way a third-party SCADA would: readHistoryValue (raw,
// following continuation points) and readAggregateValue (Average) of one node, from a server
// without security (tests/historian/test_history_read_node.py serves a store on loopback). Prints
// one line on stdout:
//   RESULT {"ok": true, "raw": {"status": N, "values": [[iso, value, status], ...]},
//           "average": {"status": N, "values": [...]}, "unknown": N}
//   RESULT {"ok": false, "error": "<message>"}
// Exit code 0 when every read returned, 1 on failure, 2 on bad usage.
//
//   node history.mjs ENDPOINT NODEID START_ISO END_ISO INTERVAL_MS
import { AggregateFunction, MessageSecurityMode, OPCUAClient, SecurityPolicy } from "node-opcua-client";

const [endpoint, nodeId, startIso, endIso, intervalMs] = process.argv.slice(2);
if (!endpoint || !nodeId || !startIso || !endIso || !intervalMs) {
  process.stderr.write("usage: node history.mjs ENDPOINT NODEID START_ISO END_ISO INTERVAL_MS\n");
  process.exit(2);
}

const rows = (result) =>
  (result.historyData?.dataValues ?? []).map((dv) => [
    dv.sourceTimestamp ? dv.sourceTimestamp.toISOString() : null,
    dv.value?.value ?? null,
    dv.statusCode.value,
  ]);

const client = OPCUAClient.create({
  applicationName: "tanklab node-opcua history client",
  securityMode: MessageSecurityMode.None,
  securityPolicy: SecurityPolicy.None,
  endpointMustExist: false,
  connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
});
try {
  await client.connect(endpoint);
  const session = await client.createSession();
  const start = new Date(startIso);
  const end = new Date(endIso);
  const raw = { status: 0, values: [] };
  let cp = null;
  for (let i = 0; i < 100; i++) {
    const r = await session.readHistoryValue({ nodeId, continuationPoint: cp }, start, end, {
      returnBounds: false,
    });
    raw.status = r.statusCode.value;
    raw.values.push(...rows(r));
    cp = r.continuationPoint;
    if (!cp || cp.length === 0) break;
  }
  const [avg] = await session.readAggregateValue(
    [{ nodeId }],
    start,
    end,
    [AggregateFunction.Average],
    Number(intervalMs),
  );
  const unknown = await session.readHistoryValue("ns=1;s=No.Such.Tag", start, end);
  await session.close();
  await client.disconnect();
  const result = {
    ok: true,
    raw,
    average: { status: avg.statusCode.value, values: rows(avg) },
    unknown: unknown.statusCode.value,
  };
  process.stdout.write(`RESULT ${JSON.stringify(result)}\n`);
  process.exit(0);
} catch (err) {
  process.stdout.write(`RESULT ${JSON.stringify({ ok: false, error: String(err?.message ?? err) })}\n`);
  await client.disconnect().catch(() => {});
  process.exit(1);
}
