/* Accountability: the roll call (a personnel accountability report, PAR) and the evacuation
   order. The commander starts one from the header; the console sends the order to every
   responder's wearable, each wearable acknowledges, and the service says in each Status who
   has answered (Status.commands). A responder who has not answered after the service's
   command_answer_s (30 s) is MISSING here and raises par_unanswered (or
   evacuation_unacknowledged) on the alarm bar. */
import {S} from "./state.js";
import {postJSON} from "./api.js";
import {$, ask, toast} from "./ui.js";

/** The roster's PAR cell: ✓ answered, waiting, MISSING, or — (no roll call yet). */
export function parText(r) {
  const s = r.status;
  const order = s && s.commands ? s.commands.par : null;
  if (!order) return S.lastRollCall && !s ? "MISSING" : "—";
  if (order.acked_at != null) return "✓";
  return (s.alarms || []).includes("par_unanswered") ? "MISSING" : "waiting";
}
export const parValue = (r) => ({"MISSING": 0, "waiting": 1, "—": 2, "✓": 3}[parText(r)]);

async function send(action) {
  const res = await postJSON("/api/command", {action});
  if (action === "par") S.lastRollCall = res;
  toast(`${action === "par" ? "Roll call" : "Evacuation order"} sent to ${res.responders.length} responder(s)`, "ok");
  return res;
}

export function bindPar() {
  $("btn-par").addEventListener("click", () => send("par").catch((e) => toast(`Roll call not sent: ${e.message}`, "error")));
  $("btn-evacuate").addEventListener("click", async () => {
    if (!(await ask("EVACUATE THE BUILDING", "Send the evacuation order to every responder's wearable?"))) return;
    send("evacuate").catch((e) => toast(`Evacuation order not sent: ${e.message}`, "error"));
  });
}
