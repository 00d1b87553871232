// What every node-opcua test client of tests/node shares: its arguments, a client that connects
// to a tanklab server exactly as README.md ("Any OPC UA client") says, one session run to the end
// on every path, the single result line, and event subscriptions read as a queue.
//
// A script calls `main(usage, names, body)`: `names` are its positional arguments (the password
// comes from $TANKLAB_PASSWORD); `body(session, args)` returns the result object and whether it
// succeeded. main prints one line on stdout (node-opcua logs there too):
//   RESULT {...the result..., "certificate": "<the client's own certificate>"}
//   RESULT {"ok": false, "error": "<message, with the OPC UA status name>", "certificate": "..."}
// Exit code 0 on success, 1 when refused or failed, 2 on bad usage.
//
// Every script's first two arguments are ENDPOINT and PKI_DIR; PKI_DIR is node-opcua's own PKI
// (OPC UA Part 12 layout): trusted/certs, trusted/crl, issuers/certs, issuers/crl, rejected,
// own/certs/client_certificate.pem and own/private/private_key.pem, the latter two made on first
// use. The server is trusted through the site CA in that PKI, or not at all.
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

/** Run a script: parse its arguments, connect, open a session, run `body`, report. */
export async function main(script, names, body, { sessionTimeoutMs = 10000 } = {}) {
  const values = process.argv.slice(2);
  const password = process.env.TANKLAB_PASSWORD;
  if (values.length < names.length || values.slice(0, names.length).some((v) => !v) || !password) {
    process.stderr.write(`usage: TANKLAB_PASSWORD=... node ${script} ${names.join(" ")}\n`);
    process.exit(2);
  }
  const args = Object.fromEntries(names.map((name, i) => [name, values[i]]));
  const client = OPCUAClient.create({
    applicationName: `tanklab node-opcua test client (${script})`,
    applicationUri: "urn:tanklab:test:node-opcua",
    securityMode: MessageSecurityMode.SignAndEncrypt,
    securityPolicy: SecurityPolicy.Basic256Sha256,
    clientCertificateManager: new OPCUACertificateManager({
      rootFolder: args.PKI_DIR,
      automaticallyAcceptUnknownCertificate: false,
    }),
    endpointMustExist: false,
    connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
    requestedSessionTimeout: sessionTimeoutMs,
  });
  const report = (result, code) => {
    process.stdout.write(`RESULT ${JSON.stringify({ ...result, certificate: client.certificateFile })}\n`);
    process.exitCode = code;
  };
  try {
    await client.connect(args.ENDPOINT);
    try {
      const session = await client.createSession({ type: UserTokenType.UserName, userName: args.USER, password });
      try {
        const { result, ok } = await body(session, args);
        report({ ok, ...result }, ok ? 0 : 1);
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
}

/** The namespace index of urn:tanklab on this server. */
export async function tanklabNamespace(session) {
  const namespaces = await session.readNamespaceArray();
  const ns = namespaces.indexOf("urn:tanklab");
  if (ns < 0) throw new Error(`namespace urn:tanklab not in ${JSON.stringify(namespaces)}`);
  return ns;
}

/**
 * Events of the Server object (OfType AlarmConditionType, the given select fields) as a queue:
 * `{subscription, next(accept, ms, what)}`; `next` resolves with the first queued or coming
 * event that `accept` takes (the ones before it are dropped), or rejects after `ms`.
 */
export async function alarmEvents(session, fields, queueSize) {
  const subscription = await session.createSubscription2({
    requestedPublishingInterval: 100,
    requestedLifetimeCount: 600,
    requestedMaxKeepAliveCount: 20,
    publishingEnabled: true,
  });
  const items = [];
  let waiter = null;
  const item = await subscription.monitor(
    { nodeId: "i=2253", attributeId: AttributeIds.EventNotifier },
    { queueSize, filter: constructEventFilter(fields, ofType("AlarmConditionType")), discardOldest: false },
    TimestampsToReturn.Both,
  );
  item.on("changed", (values) => {
    const ev = {};
    fields.forEach((name, i) => (ev[name] = values[i].value));
    items.push(ev);
    if (waiter) waiter();
  });
  const next = (accept, ms, what) =>
    new Promise((resolve, reject) => {
      const timer = setTimeout(() => reject(new Error(`timed out waiting for ${what}`)), ms);
      const look = () => {
        while (items.length) {
          const ev = items.shift();
          if (accept(ev)) {
            clearTimeout(timer);
            waiter = null;
            resolve(ev);
            return;
          }
        }
        waiter = look;
      };
      look();
    });
  return { subscription, next };
}
