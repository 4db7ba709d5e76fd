// The fleet page: one row per machine, updated as each machine's estimate arrives.
const rows = new Map();
const fmt = (v, d) => (v === null || v === undefined ? "–" : Number(v).toFixed(d));

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
    const cells = [
      name,
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
      } else if (i === 8) {
        if (r.dashboard) {
          const a = document.createElement("a");
          a.href = r.dashboard;
          a.textContent = "open";
          a.target = "_blank";
          a.rel = "noopener";
          td.append(a);
        } else td.textContent = "–";
      } else td.textContent = text;
      if (i >= 2 && i <= 4) td.className = "num";
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
