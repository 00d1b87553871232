// A node-opcua client that connects to a tanklab server exactly as README.md ("Any OPC UA
// client") says, reads one node and prints one result line on stdout (node-opcua logs there too):
//   RESULT {"ok": true, "value": <number>, "certificate": "<its own certificate>"}
//   RESULT {"ok": false, "error": "<message, with the OPC UA status name>", "certificate": "..."}
// Exit code 0 when it read the node, 1 when it was refused or failed, 2 on bad usage.
//
//   node read.mjs ENDPOINT PKI_DIR USER NODE_PATH        (password in $TANKLAB_PASSWORD)
//
// PKI_DIR is node-opcua's own PKI (OPC UA Part 12 layout): trusted/certs, trusted/crl,
// issuers/certs, issuers/crl, rejected, own/certs/client_certificate.pem and
// own/private/private_key.pem, the latter two made on first use. NODE_PATH is a tanklab dotted
// path (a string NodeId in the namespace urn:tanklab), e.g. Plant.T1.Level.
import { OPCUACertificateManager } from "node-opcua-certificate-manager";
import {
  AttributeIds,
  MessageSecurityMode,
  OPCUAClient,
  SecurityPolicy,
  UserTokenType,
} from "node-opcua-client";

const [endpoint, pkiDir, userName, nodePath] = process.argv.slice(2);
const password = process.env.TANKLAB_PASSWORD;
if (!endpoint || !pkiDir || !userName || !nodePath || !password) {
  process.stderr.write("usage: TANKLAB_PASSWORD=... node read.mjs ENDPOINT PKI_DIR USER NODE_PATH\n");
  process.exit(2);
}

const certificateManager = new OPCUACertificateManager({
  rootFolder: pkiDir,
  automaticallyAcceptUnknownCertificate: false, // a server is trusted through the CA, or not at all
});
const client = OPCUAClient.create({
  applicationName: "tanklab node-opcua test client",
  applicationUri: "urn:tanklab:test:node-opcua",
  securityMode: MessageSecurityMode.SignAndEncrypt,
  securityPolicy: SecurityPolicy.Basic256Sha256,
  clientCertificateManager: certificateManager,
  endpointMustExist: false,
  connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
  requestedSessionTimeout: 10000,
});

function report(result, code) {
  const certificate = client.certificateFile;
  process.stdout.write(`RESULT ${JSON.stringify({ ...result, certificate })}\n`);
  process.exitCode = code;
}

try {
  await client.connect(endpoint);
  try {
    const session = await client.createSession({ type: UserTokenType.UserName, userName, password });
    try {
      const namespaces = await session.readNamespaceArray();
      const ns = namespaces.indexOf("urn:tanklab");
      if (ns < 0) throw new Error(`namespace urn:tanklab not in ${JSON.stringify(namespaces)}`);
      const dataValue = await session.read({ nodeId: `ns=${ns};s=${nodePath}`, attributeId: AttributeIds.Value });
      if (!dataValue.statusCode.isGood()) throw new Error(`read ${nodePath}: ${dataValue.statusCode.name}`);
      report({ ok: true, value: dataValue.value.value }, 0);
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
