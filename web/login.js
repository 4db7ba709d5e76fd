// The login page: one POST of the token; the answer sets an HttpOnly session cookie
// (the token is kept nowhere in the page), then the dashboard opens.
const form = document.getElementById("login");
const err = document.getElementById("error");

form.addEventListener("submit", async (ev) => {
  ev.preventDefault();
  err.textContent = "";
  const token = document.getElementById("token").value;
  const r = await fetch("/api/login", {
    method: "POST",
    headers: { "content-type": "application/json" },
    body: JSON.stringify({ token }),
  });
  document.getElementById("token").value = "";
  if (r.ok) {
    location.assign("/");
    return;
  }
  const j = await r.json().catch(() => ({}));
  err.textContent = Array.isArray(j.detail) ? j.detail.map((e) => e.msg).join("; ") : `${r.status}`;
});
