/* The console server's HTTP API (client/console/server.py): JSON in, JSON out; an error's
   {"error": "..."} becomes the thrown Error's message. */

async function parse(res) {
  let data = {};
  try { data = await res.json(); } catch (e) { data = {error: `${res.status} ${res.statusText}`}; }
  if (!res.ok) throw new Error(data.error || `${res.status} ${res.statusText}`);
  return data;
}

export async function getJSON(url) {
  return parse(await fetch(url));
}

export async function postJSON(url, body) {
  return parse(await fetch(url, {method: "POST", headers: {"Content-Type": "application/json"},
                                 body: JSON.stringify(body)}));
}
