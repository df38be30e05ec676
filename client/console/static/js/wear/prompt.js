/* The man-down prompt: "ARE YOU OK?", a countdown, and one large button.

   The service decides (service/core/alarms.py): a responder motionless for a while gets
   `man_down_at` in its Status (the device time man-down will be raised at, 10 s ahead), and
   the gateway relays it in its "state" message each second. The page asks while it is set,
   counting down on its own clock: sample times and performance.now() are the same clock, so
   man_down_at - now is the time left. A tap sends "ok" with the device time of the tap; the
   service starts its no-motion clock again from it (and records it: reprocess agrees). Once
   man-down is raised the prompt stays, saying so: a tap still cancels it.

   The prompt hides at the tap and stays hidden until the service's state shows the answer
   (ok_at), so a state sent before the answer arrived does not ask again. */

export const SENT_WAIT_S = 10;  // s to wait for the service to show the answer before asking again

export class ManDownPrompt {
  /** el: the prompt's elements {box, title, count, ok}; send(msg) -> bool (link up);
     alert()/quiet(): vibration and sound. */
  constructor(el, send, {alert, quiet}) {
    Object.assign(this, {el, send, alert, quiet});
    this.state = null;  // the service's latest {man_down_at, ok_at, alarms}
    this.answeredT = null;  // device time of the latest tap not yet shown by the service
    this.log = [];  // {asked_at, man_down_at, raised_at, answered_at} per prompt (page clock, s)
    this.timer = null;
    el.ok.addEventListener("click", () => this.answer());
  }

  now() { return performance.now() / 1000; }

  /** The gateway's state (once a second). */
  update(state) {
    this.state = state;
    if (this.answeredT != null && state.ok_at != null && state.ok_at >= this.answeredT - 1e-6) this.answeredT = null;
    const waiting = this.answeredT != null && this.now() - this.answeredT < SENT_WAIT_S;
    if (state.man_down_at == null || waiting) this.hide(); else this.show();
  }

  show() {
    const s = this.state, down = (s.alarms || []).includes("man_down");
    let p = this.log[this.log.length - 1];
    if (!p || p.answered_at != null || p.closed) {
      p = {asked_at: this.now(), man_down_at: s.man_down_at, raised_at: null, answered_at: null};
      this.log.push(p);
      this.alert();
    }
    p.man_down_at = s.man_down_at;
    if (down && p.raised_at == null) { p.raised_at = this.now(); this.alert(); }
    this.el.box.className = down ? "down" : "";
    this.el.box.hidden = false;
    this.tick();
    clearInterval(this.timer);
    this.timer = setInterval(() => this.tick(), 250);
  }

  tick() {
    const s = this.state;
    if (!s || s.man_down_at == null) return;
    const left = Math.max(0, Math.ceil(s.man_down_at - this.now()));
    const down = (s.alarms || []).includes("man_down");
    this.el.count.textContent = down ? "MAN DOWN SENT TO THE CONSOLE" : `MAN DOWN IN ${left} s`;
  }

  hide() {
    clearInterval(this.timer);
    this.timer = null;
    const p = this.log[this.log.length - 1];
    if (p && !this.el.box.hidden) p.closed = true;  // moved, or answered: the next prompt is a new one
    if (!this.el.box.hidden) this.quiet();
    this.el.box.hidden = true;
  }

  answer() {
    const t = this.now();
    if (!this.send({type: "ok", t})) { this.el.count.textContent = "NOT CONNECTED — TAP AGAIN"; return; }
    const p = this.log[this.log.length - 1];
    if (p) p.answered_at = t;
    this.answeredT = t;
    this.hide();
  }
}
