/* The phone's link to the gateway (client/console/phone_gateway.py): one WebSocket at a time,
   reopened after a loss, and the frames the service has not acknowledged kept here.

   Every frame gets the next seq of this start of the page (boot). It stays in `kept` until
   the service acknowledges it (an "acked" message: Status.seq of this stream, relayed). After
   a reconnect the gateway says in "welcome" which seq it has published already; the page
   sends again every kept frame after that one, so a network loss of the phone costs no frame
   while it lasts less than KEEP frames (5 min at 10 frames a second). Frames published but
   lost between the gateway and the service are the gateway's to resend (the wearable's keep). */

export const KEEP = 3000;  // frames kept for resending
const RETRY_MAX_MS = 5000;
const SILENT_MS = 4000;  // the gateway speaks every second: this long without a word, the socket is dead

export class Link {
  constructor({url, token, device, boot, onEvent}) {
    Object.assign(this, {url, token, device, boot, onEvent});
    this.seq = 0;
    this.kept = [];  // frames not acknowledged, oldest first
    this.acked = null;  // newest seq the service took
    this.published = null;  // newest seq the gateway said it put
    this.counts = {sent: 0, resent: 0, acked: 0, reconnects: 0, refused: 0};
    this.ws = null;
    this.heardAt = 0;
    this.ready = false;  // welcomed: frames may go
    this.stopped = false;
    this.retryMs = 500;
    this.connectedSince = null;
  }

  start() {
    this.stopped = false;
    this.open();
    // a socket can stay "open" through a network loss (a phone between cells, a Wi-Fi that went
    // away): a silent gateway or the browser's offline event closes it, and the next opens
    addEventListener("offline", () => this.drop("offline"));
    addEventListener("online", () => { if (!this.ws || this.ws.readyState > 1) { this.retryMs = 500; this.open(); } });
    this.watchdog = setInterval(() => {
      if (this.ready && performance.now() - this.heardAt > SILENT_MS) this.drop("gateway silent");
    }, 1000);
  }

  /** Give up on the current socket (it is dead or the network is gone); reopen after a while. */
  drop(why) {
    const ws = this.ws;
    if (!ws || ws.readyState > 1) return;
    this.ws = null;
    this.ready = false;
    this.connectedSince = null;
    try { ws.close(4000, why); } catch (e) { /* closing anyway */ }
    this.onEvent("down", {code: 4000, reason: why});
    if (!this.stopped) setTimeout(() => { this.counts.reconnects++; this.open(); }, this.retryMs);
  }

  stop() {
    this.stopped = true;
    clearInterval(this.watchdog);
    if (this.ws) this.ws.close(1000, "stopped");
  }

  open() {
    if (this.stopped || (this.ws && this.ws.readyState <= 1)) return;  // one socket at a time
    const ws = new WebSocket(this.url);
    this.ws = ws;
    ws.onopen = () => ws.send(JSON.stringify({type: "hello", token: this.token, device: this.device, boot: this.boot}));
    ws.onmessage = (ev) => { this.heardAt = performance.now(); this.receive(JSON.parse(ev.data)); };
    ws.onclose = (ev) => {
      if (this.ws !== ws) return;
      this.ready = false;
      this.connectedSince = null;
      this.onEvent("down", {code: ev.code, reason: ev.reason});
      if (ev.code === 4401) { this.stopped = true; this.onEvent("revoked", {reason: ev.reason}); return; }
      if (!this.stopped) {
        setTimeout(() => { this.counts.reconnects++; this.open(); }, this.retryMs);
        this.retryMs = Math.min(RETRY_MAX_MS, this.retryMs * 2);
      }
    };
  }

  receive(m) {
    if (m.type === "welcome") {
      this.ready = true;
      this.retryMs = 500;
      this.connectedSince = performance.now();
      this.published = m.published;
      this.ack(m.acked);
      const from = m.published == null ? -1 : m.published;
      for (const f of this.kept) if (f.seq > from) { this.put(f, true); }
    } else if (m.type === "acked") {
      this.ack(m.seq);
    } else if (m.type === "refused") {
      this.counts.refused++;
    }
    this.onEvent(m.type, m);
  }

  ack(seq) {
    if (seq == null) return;
    if (this.acked == null || seq > this.acked) this.acked = seq;
    let i = 0;
    while (i < this.kept.length && this.kept[i].seq <= this.acked) i++;
    if (i) { this.kept.splice(0, i); this.counts.acked = this.acked + 1; }
  }

  /** A frame from the sensors: numbered, kept, and sent when the link is up. */
  frame(f, extra) {
    const msg = {type: "frame", seq: this.seq++, ...f, ...extra};
    this.kept.push(msg);
    if (this.kept.length > KEEP) this.kept.shift();
    if (this.ready) this.put(msg, false);
    return msg.seq;
  }

  put(msg, resent) {
    const m = resent ? {...msg, resent: true} : msg;
    try { this.ws.send(JSON.stringify(m)); } catch (e) { return; }
    if (resent) this.counts.resent++; else this.counts.sent++;
  }

  /** Any other message (fix, ack): sent now if the link is up, else dropped (false). */
  send(msg) {
    if (!this.ready) return false;
    this.ws.send(JSON.stringify(msg));
    return true;
  }

  get pending() { return this.kept.length; }
}
