// The fleet page: one row per machine, updated as each machine's estimate arrives.
const rows = new Map();

// a row's link: an http(s) URL only (the fleet chose it; a script URL never becomes a link)
function safeLink(url) {
  try {
    const u = new URL(url, location.href);
    return u.protocol === "http:" || u.protocol === "https:" ? u.href : null;
  } catch {
    return null;
  }
}
const fmt = (v, d) => (v === null || v === undefined ? "–" : Number(v).toFixed(d));
const KIND = {
  breakage: "tool breakage", collision: "collision / overload", missing_tool: "missing tool",
  wear_limit: "wear limit", life_short: "tool life short",
};

// the latest unacknowledged event: what, where (tool, line, part), when; its message below
function eventCell(td, ev, unacked) {
  td.className = "event";
  if (!ev) { td.textContent = "–"; return; }
  const where = [ev.tool ? `T${ev.tool}` : null, ev.line ? `line ${ev.line}` : null,
    ev.part >= 0 ? `part ${ev.part}` : null, `t ${Number(ev.t).toFixed(2)} s`].filter(Boolean);
  td.textContent = `${KIND[ev.kind] || ev.kind} · ${where.join(" · ")}` +
    (unacked > 1 ? ` (+${unacked - 1} more)` : "");
  td.dataset.kind = ev.kind;
  const small = document.createElement("small");
  small.textContent = ev.message;
  td.append(small);
}

function render() {
  const body = document.getElementById("rows");
  const names = [...rows.keys()].sort();
  document.getElementById("empty").hidden = names.length > 0;
  document.getElementById("count").textContent = `${names.length} machine(s)`;
  body.replaceChildren(...names.map((name) => {
    const r = rows.get(name);
    const tr = document.createElement("tr");
    tr.className = r.status;
    tr.dataset.machine = name;
    tr.dataset.monitor = r.monitor || "";
    const cells = [
      name,
      null,
      null,
      null,
      fmt(r.force, 2),
      fmt(r.wear_vb_mm, 3),
      fmt(r.remaining_life_min, 1),
      r.alarms.join(", ") || "–",
      `${fmt(r.last_seen_s, 1)} s ago`,
      r.source || "–",
      null,
    ];
    cells.forEach((text, i) => {
      const td = document.createElement("td");
      if (i === 1) {
        const s = document.createElement("span");
        s.className = `status ${r.status}`;
        s.textContent = r.status;
        td.append(s);
      } else if (i === 2) {
        const s = document.createElement("span");
        s.className = `monitor ${r.monitor || ""}`;
        s.textContent = r.monitor || "–";
        td.append(s);
      } else if (i === 3) {
        eventCell(td, r.event, r.unacked);
      } else if (i === 10) {
        const href = r.dashboard ? safeLink(r.dashboard) : null;
        if (href) {
          const a = document.createElement("a");
          a.href = href;
          a.textContent = "open";
          a.target = "_blank";
          a.rel = "noopener";
          td.append(a);
        } else td.textContent = "–";
      } else td.textContent = text;
      if (i >= 4 && i <= 6) td.className = "num";
      tr.append(td);
    });
    return tr;
  }));
}

function connect() {
  const conn = document.getElementById("conn");
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
  ws.onopen = () => { conn.textContent = "live"; conn.className = "conn up"; };
  ws.onclose = () => {
    conn.textContent = "reconnecting…";
    conn.className = "conn";
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    const msg = JSON.parse(ev.data);
    if (Array.isArray(msg.rows)) {
      rows.clear();
      for (const r of msg.rows) rows.set(r.machine, r);
    } else if (msg.machine) rows.set(msg.machine, msg);
    render();
  };
}

render();
connect();
