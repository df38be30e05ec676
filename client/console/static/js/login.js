/* Who is at the keyboard. Before anything else the page asks GET /api/session: the open demo
   (no roster: whoever is at this machine acts as "local", and the header says DEMO), an
   operator or viewer already logged in, or the login form (#login): the per-incident
   password `firetrack certs issue` printed, or the browser's client certificate when the
   page is on HTTPS. The header shows who is logged in, with LOG OUT. A viewer's page hides
   the actions (body.viewer); the server refuses them anyway. */
import {S} from "./state.js";
import {$, setText, toast} from "./ui.js";
import {getJSON, postJSON} from "./api.js";

function show(session) {
  S.session = session;
  const who = $("who");
  who.hidden = false;
  document.body.classList.toggle("viewer", session.role === "viewer");
  if (session.auth === "open") {
    setText($("who-name"), "DEMO — NO LOGIN, THIS MACHINE ONLY");
    who.classList.add("insecure");
    $("btn-logout").hidden = true;
  } else {
    setText($("who-name"), `${session.user} · ${session.role.toUpperCase()}`);
    $("btn-logout").hidden = false;
  }
}

function form(info) {
  return new Promise((resolve) => {
    $("login").hidden = false;
    setText($("login-incident"), info.incident || "");
    $("login-cert").hidden = !info.certificate;
    if (info.certificate) setText($("login-cert"), `LOG IN AS ${info.certificate} (CERTIFICATE)`);
    const done = (session) => { $("login").hidden = true; $("login-error").textContent = ""; resolve(session); };
    const failed = (e) => { setText($("login-error"), e.message); $("login-password").select(); };
    $("login-form").onsubmit = async (ev) => {
      ev.preventDefault();
      try {
        done(await postJSON("/api/login", {user: $("login-user").value.trim(), password: $("login-password").value}));
      } catch (e) { failed(e); }
    };
    $("login-cert").onclick = async () => {
      try { done(await postJSON("/api/login", {certificate: true})); } catch (e) { failed(e); }
    };
    $("login-user").focus();
  });
}

/** Resolves once someone may use the page (logged in, or the open demo). */
export async function login() {
  const info = await getJSON("/api/session");
  const session = info.user ? info : await form(info);
  show(session);
  $("btn-logout").onclick = async () => {
    try { await postJSON("/api/logout", {}); } catch (e) { toast(`Logout: ${e.message}`, "error"); }
    location.reload();
  };
  return session;
}

/** The session ended (logged out elsewhere, revoked, expired): back to the login form. */
export function sessionEnded() {
  toast("Your session ended: log in again", "error");
  setTimeout(() => location.reload(), 1500);
}
