/* Phones as wearables: the operator enrols a phone for the selected responder (a QR code and
   a short code from POST /api/phones, which the phone trades for its token at /wear) and
   revokes every phone of a responder at once (POST /api/phones/revoke). */
import {S} from "./state.js";
import {$, ask, setText, toast} from "./ui.js";
import {postJSON} from "./api.js";

export function renderPhoneButtons() {
  $("btn-phone").disabled = $("btn-phone-revoke").disabled = !S.selected;
}

export function bindPhones() {
  $("btn-phone").addEventListener("click", async () => {
    const rid = S.selected;
    if (!rid) return;
    try {
      const g = await postJSON("/api/phones", {responder: rid});
      setText($("phone-for"), rid);
      $("phone-qr").innerHTML = g.qr_svg;  // an SVG the console made of its own address
      setText($("phone-code"), g.code);
      setText($("phone-url"), g.url.split("#")[0]);
      $("phone-enrol").hidden = false;
    } catch (e) {
      toast(`No phone enrolment for ${rid}: ${e.message}`, "error");
    }
  });
  $("phone-close").addEventListener("click", () => { $("phone-enrol").hidden = true; });
  $("btn-phone-revoke").addEventListener("click", async () => {
    const rid = S.selected;
    if (!rid || !(await ask(`REVOKE ${rid}'S PHONES?`, "Every phone enrolled for this responder stops publishing now."))) return;
    try {
      const r = await postJSON("/api/phones/revoke", {responder: rid});
      toast(`${r.revoked} phone enrolment(s) of ${rid} revoked`);
    } catch (e) {
      toast(`Revoking ${rid}'s phones failed: ${e.message}`, "error");
    }
  });
}
