/* Small page helpers: element lookup, text that only changes when it differs, durations,
   toasts, and the confirmation dialog (#modal). */

const TOAST_MS = 6000;
const TOAST_ERROR_MS = 12000;
const TOASTS_SHOWN = 4;

export const $ = (id) => document.getElementById(id);

/** How the wearable's motion state reads on screen. */
export const MOTION_LABELS = {walking: "walking", running: "running", crawling: "crawling", stairs: "stairs",
                              still: "still", no_motion: "NO MOTION"};

/** Set an element's text only when it changes (no needless layout work on timers). */
export function setText(el, text) { if (el.textContent !== text) el.textContent = text; }

/** A duration (s) as people read it: "12 s", "3 min 5 s", "1 h 4 min"; "—" when unknown. */
export function ago(s) {
  if (!(s >= 0)) return "—";
  if (s < 60) return `${Math.round(s)} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${Math.round(s % 60)} s`;
  return `${Math.floor(s / 3600)} h ${Math.floor((s % 3600) / 60)} min`;
}

/** A short notice at the bottom left; kind "ok" or "error". */
export function toast(text, kind = "") {
  const el = document.createElement("div");
  el.className = "toast " + kind;
  el.textContent = text;
  $("toasts").appendChild(el);
  while ($("toasts").children.length > TOASTS_SHOWN) $("toasts").firstChild.remove();
  setTimeout(() => el.remove(), kind === "error" ? TOAST_ERROR_MS : TOAST_MS);
}

let modalResolve = null;

/** Ask for confirmation (input null) or for a text: resolves true / the text, or null when cancelled. */
export function ask(title, text, input = null) {
  $("modal-title").textContent = title;
  $("modal-text").textContent = text;
  const inp = $("modal-input");
  inp.hidden = input === null;
  inp.value = input || "";
  $("modal").hidden = false;
  (input === null ? $("modal-ok") : inp).focus();
  return new Promise((resolve) => { modalResolve = resolve; });
}

function closeModal(ok) {
  if ($("modal").hidden) return;
  $("modal").hidden = true;
  const value = $("modal-input").hidden ? true : $("modal-input").value.trim();
  const r = modalResolve; modalResolve = null;
  if (r) r(ok ? value : null);
}

export const modalOpen = () => !$("modal").hidden;

export function bindModal() {
  $("modal-ok").onclick = () => closeModal(true);
  $("modal-cancel").onclick = () => closeModal(false);
  document.addEventListener("keydown", (e) => {
    if (!modalOpen()) return;
    if (e.key === "Escape") closeModal(false);
    else if (e.key === "Enter") closeModal(true);
  });
}
