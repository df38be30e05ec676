/* The console server's HTTP API (client/console/server.py): JSON in, JSON out; an error's
   {"error": "..."} becomes the thrown Error's message, its HTTP status the Error's status
   (401: the session ended, log in again). The session is an HttpOnly cookie the browser
   sends by itself: no script here ever sees it. */

async function parse(res) {
  let data = {};
  try { data = await res.json(); } catch (e) { data = {error: `${res.status} ${res.statusText}`}; }
  if (!res.ok) {
    const err = new Error(data.error || `${res.status} ${res.statusText}`);
    err.status = res.status;
    throw err;
  }
  return data;
}

export async function getJSON(url) {
  return parse(await fetch(url));
}

export async function postJSON(url, body) {
  return parse(await fetch(url, {method: "POST", headers: {"Content-Type": "application/json"},
                                 credentials: "same-origin", body: JSON.stringify(body)}));
}
