// The live stream's message checks (client side). The schema itself (VERSION, SCHEMA and
// every message's JSDoc type) is web/schema.js, generated from the server's message models
// (server/service/messages.py) by `make schema`; tests/service/test_protocol.py fails when
// it is stale, and runs checkMessage under node on the frames the server really sends.
import { SCHEMA, VERSION } from "./schema.js";

export { SCHEMA, VERSION };

// The pages' one REST helper: JSON in and out (``raw``: the body sent as bytes, an upload),
// a closed session (401) back to the login page, and a refusal thrown as an Error whose
// message is the server's: a 422's fields' messages, the detail text, or the HTTP status.
export async function request(method, path, body, raw = false) {
  const type = raw ? "application/octet-stream" : "application/json";
  const init = { method, headers: { "content-type": type } };
  if (body !== undefined) init.body = raw ? body : JSON.stringify(body);
  const r = await fetch(path, init);
  if (r.status === 401) location.assign("/login");
  const j = await r.json().catch(() => ({}));
  if (!r.ok) throw new Error(refusal(j.detail, r));
  return j;
}

function refusal(detail, r) {
  if (Array.isArray(detail)) return detail.map((e) => e.msg || JSON.stringify(e)).join("; ");
  return detail === undefined || detail === null ? `${r.status} ${r.statusText}` : String(detail);
}

// fields a message may lack (the model's default): a stream without the process monitor
// sends no status; parts default to none
const OPTIONAL = { data: new Set(["status", "parts"]) };

function missing(obj, fields, kind = "") {
  const opt = OPTIONAL[kind] || new Set();
  return fields.filter((f) => !(f in obj) && !opt.has(f));
}

// Parse one text message; returns the object or throws an Error naming what is wrong.
export function checkMessage(text) {
  const msg = JSON.parse(text);
  if (msg === null || typeof msg !== "object") throw new Error("message is not an object");
  const kind = msg.type;
  if (kind !== "hello" && kind !== "data" && kind !== "event") {
    throw new Error(`unknown message type ${kind}`);
  }
  const miss = missing(msg, SCHEMA[kind], kind);
  if (miss.length) throw new Error(`${kind} message lacks ${miss.join(", ")}`);
  if (kind === "event") {
    // a monitor event, when raised and again when acknowledged (same id)
    const m = missing(msg.event, SCHEMA.event_record);
    if (m.length) throw new Error(`event lacks ${m.join(", ")}`);
  } else if (kind === "hello") {
    if (msg.version !== VERSION) {
      throw new Error(`protocol version ${msg.version}, this page speaks ${VERSION}`);
    }
    for (const c of msg.channels) {
      const m = missing(c, SCHEMA.channel);
      if (m.length) throw new Error(`channel lacks ${m.join(", ")}`);
      if (c.grid !== "t" && c.grid !== "ts") throw new Error(`channel ${c.name}: grid ${c.grid}`);
    }
    for (const c of msg.charts) {
      const m = missing(c, SCHEMA.chart);
      if (m.length) throw new Error(`chart lacks ${m.join(", ")}`);
    }
    for (const p of msg.parts) {
      const m = missing(p, SCHEMA.part);
      if (m.length) throw new Error(`part lacks ${m.join(", ")}`);
    }
  } else {
    const m = missing(msg.health, SCHEMA.health);
    if (m.length) throw new Error(`health lacks ${m.join(", ")}`);
    const a = missing(msg.accuracy, SCHEMA.accuracy);
    if (a.length) throw new Error(`accuracy lacks ${a.join(", ")}`);
    // the monitor's status (the strip): required once the stream's Data carries it
    if (msg.status !== undefined && msg.status !== null) {
      const st = missing(msg.status, SCHEMA.status);
      if (st.length) throw new Error(`status lacks ${st.join(", ")}`);
    }
    if (!["truth", "measured_force", "none"].includes(msg.accuracy.mode)) {
      throw new Error(`accuracy mode ${msg.accuracy.mode}`);
    }
    // each channel lies on one of the two grids: t (fast) or ts (slow)
    for (const [name, arr] of Object.entries(msg.ch)) {
      if (arr.length !== msg.t.length && arr.length !== msg.ts.length) {
        throw new Error(`channel ${name}: ${arr.length} samples, t has ${msg.t.length}, ` +
                        `ts has ${msg.ts.length}`);
      }
    }
  }
  return msg;
}
