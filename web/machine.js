// One machine of a `cutwatch worker`: its latest estimates, polled twice a second from
// ../../api/machines/<name> (same origin, the worker's session cookie or token).
const name = decodeURIComponent(location.pathname.split("/").filter(Boolean).pop() || "");
const api = `../../api/machines/${encodeURIComponent(name)}`;
const $ = (id) => document.getElementById(id);
$("title").textContent = `cutwatch — ${name}`;
document.title = `cutwatch — ${name}`;

const fmt = (v) => (v === null || v === undefined ? "—"
  : typeof v === "number" ? (Math.abs(v) >= 1e4 || (v !== 0 && Math.abs(v) < 1e-3) ? v.toExponential(3) : v.toFixed(4))
  : String(v));

function rows(el, obj) {
  el.replaceChildren(...Object.entries(obj).map(([k, v]) => {
    const tr = document.createElement("tr");
    const th = document.createElement("th");
    th.textContent = k;
    const td = document.createElement("td");
    td.className = "num";
    td.textContent = fmt(v);
    tr.append(th, td);
    return tr;
  }));
}

function plot(levels) {
  const c = $("levels");
  const g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  if (levels.length < 2) return;
  const ys = levels.map((p) => p[1]);
  const lo = Math.min(...ys), hi = Math.max(...ys), span = hi - lo || 1;
  g.strokeStyle = "#1565c0";
  g.beginPath();
  levels.forEach(([, y], i) => {
    const px = (i / (levels.length - 1)) * (c.width - 10) + 5;
    const py = c.height - 5 - ((y - lo) / span) * (c.height - 20);
    if (i === 0) g.moveTo(px, py); else g.lineTo(px, py);
  });
  g.stroke();
  g.fillStyle = "#68707c";
  g.fillText(`${hi.toFixed(3)}`, 4, 12);
  g.fillText(`${lo.toFixed(3)}`, 4, c.height - 8);
}

async function poll() {
  try {
    const r = await fetch(api, { headers: { accept: "application/json" } });
    if (r.status === 401) { location.href = "../../login"; return; }
    if (!r.ok) throw new Error(`${r.status}`);
    const m = await r.json();
    $("conn").textContent = `t ${fmt(m.t)} s`;
    $("conn").classList.add("up");
    $("worker").textContent = `worker ${m.worker} · ${m.blocks} blocks · ${m.events} events`;
    rows($("values"), m.latest);
    rows($("status"), m.status || {});
    const f = m.feed || {};
    rows($("feed"), {
      state: f.state, blocks: f.blocks, gaps: f.gaps, dropped_samples: f.dropped_samples,
      resumed: m.checkpoint.resumed, resumed_t: m.checkpoint.resumed_t, saved_t: m.checkpoint.saved_t,
    });
    plot(m.levels || []);
  } catch (e) {
    $("conn").textContent = `no answer (${e.message})`;
    $("conn").classList.remove("up");
  }
}
poll();
setInterval(poll, 500);
