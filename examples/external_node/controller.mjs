// An external controller over OPC UA with node-opcua: the same PI in velocity form as
// examples/external_asyncua.py, to show that the External role is not Python-only.
//
//   npm ci            # once, here: the pinned node-opcua of package-lock.json
//   node controller.mjs --url opc.tcp://127.0.0.1:4841/tanklab/plc --home ~/.config/tanklab \
//        --name mypi --loop LIC1 --sp 0.45 [--kp 1.5e-3] [--ki 2e-5] [--period 0.5] [--pki DIR]
//
// Before: `tankctl user add-external mypi` (the certificate in role External) and an Engineer
// writes PLC.LIC1.RemoteSource = EXTERNAL (1). The client's channel certificate and its X509
// identity are both the External certificate; node-opcua's own PKI (--pki, default ./pki) gets the
// site CA and its CRL in trusted/ (node-opcua refuses a server whose issuer or CRL it lacks).
// Each period: e = SP - PV [m]; u += Kp (e - e_prev) + Ki dt e, clamped to RemoteMV's EURange;
// dt is the PLC's model time between samples [s]. Writes RemoteMV and a new heartbeat. Ctrl-C or
// SIGTERM: the loop back to AUTO, exit 0. Killed: the PLC's watchdog sheds the loop to AUTO.
import fs from "node:fs";
import os from "node:os";
import path from "node:path";
import { OPCUACertificateManager } from "node-opcua-certificate-manager";
import {
  AttributeIds, DataType, MessageSecurityMode, OPCUAClient, SecurityPolicy, UserTokenType, makeBrowsePath,
} from "node-opcua-client";

const AUTO = 1, REMOTE = 2; // PLC.LIC{j}.Mode
const opts = { url: "opc.tcp://127.0.0.1:4841/tanklab/plc", home: path.join(os.homedir(), ".config/tanklab"),
  loop: "LIC1", kp: "1.5e-3", ki: "2e-5", period: "0.5", pki: "pki" };
for (let i = 2; i + 1 < process.argv.length; i += 2) opts[process.argv[i].replace(/^--/, "")] = process.argv[i + 1];
if (!opts.name || opts.sp === undefined) {
  process.stderr.write("usage: node controller.mjs --name NAME --sp LEVEL_M [--url URL] [--home DIR] [--loop LIC1]\n");
  process.exit(2);
}
const [sp, kp, ki, periodMs] = [Number(opts.sp), Number(opts.kp), Number(opts.ki), 1000 * Number(opts.period)];
const site = path.join(opts.home, "pki");
const pem = (der, kind) => `-----BEGIN ${kind}-----\n${der.toString("base64").match(/.{1,64}/g).join("\n")}\n-----END ${kind}-----\n`;
for (const sub of ["trusted/certs", "trusted/crl", "own/certs"]) fs.mkdirSync(path.join(opts.pki, sub), { recursive: true });
fs.copyFileSync(path.join(site, "ca", "ca-cert.pem"), path.join(opts.pki, "trusted/certs/tanklab-ca.pem"));
fs.copyFileSync(path.join(site, "crl", "ca.crl.pem"), path.join(opts.pki, "trusted/crl/tanklab-ca.crl.pem"));
const certFile = path.join(opts.pki, "own/certs", `external-${opts.name}.pem`);
const certDer = fs.readFileSync(path.join(site, "own", `external-${opts.name}.der`));
fs.writeFileSync(certFile, pem(certDer, "CERTIFICATE"));
const keyFile = path.join(site, "private", `external-${opts.name}.pem`);

const client = OPCUAClient.create({
  applicationName: `tanklab external controller ${opts.name}`,
  applicationUri: `urn:tanklab:external-${opts.name}`, // as in the certificate
  securityMode: MessageSecurityMode.SignAndEncrypt,
  securityPolicy: SecurityPolicy.Basic256Sha256,
  certificateFile: certFile,
  privateKeyFile: keyFile,
  clientCertificateManager: new OPCUACertificateManager({ rootFolder: opts.pki, automaticallyAcceptUnknownCertificate: false }),
  endpointMustExist: false,
  connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
});
let stop = false;
const wake = { fn: null };
for (const sig of ["SIGINT", "SIGTERM"]) process.on(sig, () => { stop = true; if (wake.fn) wake.fn(); });
const sleep = (ms) => new Promise((resolve) => { const t = setTimeout(resolve, ms); wake.fn = () => { clearTimeout(t); resolve(); }; });

await client.connect(opts.url);
const session = await client.createSession({
  type: UserTokenType.Certificate, certificateData: certDer, privateKey: fs.readFileSync(keyFile, "utf8"),
});
try {
  const ns = (await session.readNamespaceArray()).indexOf("urn:tanklab");
  const id = (p) => `ns=${ns};s=${p}`;
  const L = `PLC.${opts.loop}`;
  const read = async (p) => {
    const dv = await session.read({ nodeId: id(p), attributeId: AttributeIds.Value });
    if (!dv.statusCode.isGood()) throw new Error(`read ${p}: ${dv.statusCode.name}`);
    return dv.value.value;
  };
  const write = async (p, value, dataType) => {
    const sc = await session.write({ nodeId: id(p), attributeId: AttributeIds.Value, value: { value: { dataType, value } } });
    if (!sc.isGood()) throw new Error(`write ${p}: ${sc.name}`);
  };
  const found = await session.translateBrowsePath(makeBrowsePath(id(`${L}.RemoteMV`), "/EURange"));
  const range = (await session.read({ nodeId: found.targets[0].targetId, attributeId: AttributeIds.Value })).value.value;
  let beat = await read("PLC.External.Heartbeat");
  const heartbeat = async () => { beat = (beat + 1) % 2 ** 32; await write("PLC.External.Heartbeat", beat, DataType.UInt32); };
  await heartbeat();
  let u = await read(`${L}.MV`);
  if ((await read(`${L}.Mode`)) !== REMOTE) {
    await write(`${L}.RemoteMV`, u, DataType.Double);
    await write(`${L}.Mode`, REMOTE, DataType.Int32);
  }
  console.log(`driving ${opts.loop} in REMOTE to SP ${sp} m from MV ${u}`);
  let ePrev = null, tPrev = null;
  while (!stop) {
    const [pv, t] = [await read(`${L}.PV`), await read("PLC.Status.ModelTime")];
    const e = sp - pv;
    if (ePrev !== null && t > tPrev) u = Math.min(Math.max(u + kp * (e - ePrev) + ki * (t - tPrev) * e, range.low), range.high);
    if (tPrev === null || t > tPrev) [ePrev, tPrev] = [e, t];
    await write(`${L}.RemoteMV`, u, DataType.Double);
    await heartbeat();
    await sleep(periodMs);
  }
  await write(`${L}.Mode`, AUTO, DataType.Int32); // hand the loop back, bumpless
  console.log(`${opts.loop} back in AUTO`);
} finally {
  await session.close();
  await client.disconnect();
}
