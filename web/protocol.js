// The live stream's message schema (client side); its twin is server/protocol.py.
// tests/test_protocol.py runs this module under node and checks SCHEMA equals the
// server's, and that checkMessage accepts the frames the server really sends.

export const VERSION = 1;

export const SCHEMA = {
  version: VERSION,
  hello: ["type", "version", "channels", "sample_time", "scenario", "knobs"],
  channel: ["name", "unit", "group", "label"],
  data: ["type", "dropped", "seq", "wall", "t", "ch", "health", "knobs"],
  health: ["sim_t", "speed", "paused", "lag_ms", "lag_p99_ms", "realtime_factor",
           "clients", "dropped_total", "stalls"],
};

function missing(obj, fields) {
  return fields.filter((f) => !(f in obj));
}

// Parse one text message; returns the object or throws an Error naming what is wrong.
export function checkMessage(text) {
  const msg = JSON.parse(text);
  if (msg === null || typeof msg !== "object") throw new Error("message is not an object");
  const kind = msg.type;
  if (kind !== "hello" && kind !== "data") throw new Error(`unknown message type ${kind}`);
  const miss = missing(msg, SCHEMA[kind]);
  if (miss.length) throw new Error(`${kind} message lacks ${miss.join(", ")}`);
  if (kind === "hello") {
    if (msg.version !== VERSION) {
      throw new Error(`protocol version ${msg.version}, this page speaks ${VERSION}`);
    }
    for (const c of msg.channels) {
      const m = missing(c, SCHEMA.channel);
      if (m.length) throw new Error(`channel lacks ${m.join(", ")}`);
    }
  } else {
    const m = missing(msg.health, SCHEMA.health);
    if (m.length) throw new Error(`health lacks ${m.join(", ")}`);
    for (const [name, arr] of Object.entries(msg.ch)) {
      if (arr.length !== msg.t.length) {
        throw new Error(`channel ${name}: ${arr.length} samples, t has ${msg.t.length}`);
      }
    }
  }
  return msg;
}
