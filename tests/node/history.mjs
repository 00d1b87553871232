// A node-opcua client that reads a tag's history from the tanklab historian (issue #16) with
// node-opcua's own calls: readHistoryValue (ReadRawModifiedDetails, following continuation points
// until the server has none left) and readAggregateValue (ReadProcessedDetails, Average over
// INTERVAL_MS). One result line on stdout:
//   RESULT {"ok": true, "raw": [[<source time ISO>, <value>, "<StatusCode name>"], ...], "pages": <n>,
//           "average": [[<time ISO>, <value or null>, "<StatusCode name>"], ...], "certificate": "..."}
//   RESULT {"ok": false, "error": "<message>", "certificate": "..."}
// Exit code 0 when both reads answered Good, 1 otherwise, 2 on bad usage.
//
//   node history.mjs ENDPOINT PKI_DIR USER NODE_PATH START END INTERVAL_MS   (password in $TANKLAB_PASSWORD)
//
// START and END are ISO 8601 times; NODE_PATH a tanklab dotted path (ns urn:tanklab), e.g.
// PLC.LIC1.PV. PKI_DIR is node-opcua's own PKI (session.mjs says its layout).
import { AggregateFunction } from "node-opcua-client";
import { main, tanklabNamespace } from "./session.mjs";

const rows = (dataValues) =>
  (dataValues || []).map((dv) => [
    dv.sourceTimestamp ? dv.sourceTimestamp.toISOString() : null,
    dv.value && dv.value.value !== undefined ? dv.value.value : null,
    dv.statusCode.name,
  ]);

await main(
  "history.mjs",
  ["ENDPOINT", "PKI_DIR", "USER", "NODE_PATH", "START", "END", "INTERVAL_MS"],
  async (session, args) => {
    const nodeId = `ns=${await tanklabNamespace(session)};s=${args.NODE_PATH}`;
    const start = new Date(args.START);
    const end = new Date(args.END);
    const raw = [];
    let pages = 0;
    let continuationPoint;
    do {
      const result = await session.readHistoryValue({ nodeId, continuationPoint }, start, end, {
        returnBounds: false,
        numValuesPerNode: 1000,
      });
      pages += 1;
      if (!result.statusCode.isGood()) throw new Error(`readHistoryValue: ${result.statusCode.name}`);
      raw.push(...rows(result.historyData.dataValues));
      continuationPoint = result.continuationPoint && result.continuationPoint.length ? result.continuationPoint : undefined;
    } while (continuationPoint);
    const [processed] = await session.readAggregateValue(
      [{ nodeId }],
      start,
      end,
      [AggregateFunction.Average],
      Number(args.INTERVAL_MS),
    );
    if (!processed.statusCode.isGood()) throw new Error(`readAggregateValue: ${processed.statusCode.name}`);
    return { result: { raw, pages, average: rows(processed.historyData.dataValues) }, ok: true };
  },
);
