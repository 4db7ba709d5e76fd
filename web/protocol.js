// The live stream's message schema (client side); its twin is server/protocol.py.
// tests/test_protocol.py runs this module under node and checks SCHEMA equals the
// server's, and that checkMessage accepts the frames the server really sends.

export const VERSION = 1;
// channel groups on the fast grid t; every other group is on ts (see server/protocol.py)
export const FAST_GROUPS = ["force"];

// identified parameter -> its channels: estimate, 95 % bounds, excited flag (1/0; 0: show
// the parameter greyed, "not excited", not as a number)
export const INTERVALS = Object.fromEntries(
  ["J_L", "B_L", "F_CL"].map((q) => [
    q, { estimate: `${q}_seg`, lower: `${q}_lo`, upper: `${q}_hi`, excited: `${q}_excited` },
  ]),
);

export const SCHEMA = {
  version: VERSION,
  hello: ["type", "version", "channels", "sample_time", "scenario", "knobs"],
  channel: ["name", "unit", "group", "label", "grid"],
  data: ["type", "dropped", "seq", "wall", "t", "ts", "ch", "health", "knobs", "accuracy"],
  fast_groups: FAST_GROUPS,
  health: ["sim_t", "speed", "paused", "lag_ms", "lag_p99_ms", "realtime_factor",
           "clients", "dropped_total", "stalls"],
  // rolling rms of each force estimate (server/protocol.py): mode "truth" or "agreement"
  accuracy: ["mode", "windows", "span", "rms", "rms_q", "floor", "mean_of"],
  intervals: INTERVALS,
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
      if (c.grid !== "t" && c.grid !== "ts") throw new Error(`channel ${c.name}: grid ${c.grid}`);
    }
  } else {
    const m = missing(msg.health, SCHEMA.health);
    if (m.length) throw new Error(`health lacks ${m.join(", ")}`);
    const a = missing(msg.accuracy, SCHEMA.accuracy);
    if (a.length) throw new Error(`accuracy lacks ${a.join(", ")}`);
    if (msg.accuracy.mode !== "truth" && msg.accuracy.mode !== "agreement") {
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
