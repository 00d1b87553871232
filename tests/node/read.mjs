// A node-opcua client that connects to a tanklab server exactly as README.md ("Any OPC UA
// client") says, reads one node and prints one result line on stdout (node-opcua logs there too):
//   RESULT {"ok": true, "value": <number>, "certificate": "<its own certificate>"}
//   RESULT {"ok": false, "error": "<message, with the OPC UA status name>", "certificate": "..."}
// Exit code 0 when it read the node, 1 when it was refused or failed, 2 on bad usage.
//
//   node read.mjs ENDPOINT PKI_DIR USER NODE_PATH        (password in $TANKLAB_PASSWORD)
//
// PKI_DIR is node-opcua's own PKI (session.mjs says its layout). NODE_PATH is a tanklab dotted
// path (a string NodeId in the namespace urn:tanklab), e.g. Plant.T1.Level.
import { AttributeIds } from "node-opcua-client";
import { main, tanklabNamespace } from "./session.mjs";

await main("read.mjs", ["ENDPOINT", "PKI_DIR", "USER", "NODE_PATH"], async (session, { NODE_PATH }) => {
  const ns = await tanklabNamespace(session);
  const dataValue = await session.read({ nodeId: `ns=${ns};s=${NODE_PATH}`, attributeId: AttributeIds.Value });
  if (!dataValue.statusCode.isGood()) throw new Error(`read ${NODE_PATH}: ${dataValue.statusCode.name}`);
  return { result: { value: dataValue.value.value }, ok: true };
});
