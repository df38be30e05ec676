/* The phone's motion sensors in the project's units and body frame, cut into wire frames.
   Pure: no DOM, no clocks, no network (tests run it in Chromium as it is).

   Body frame. The IPIN loader's phones (pdr/io/ipin.py, Android's sensor frame) and the W3C
   device coordinate system are the same frame: x to the right of the screen, y up along the
   screen, z out of the screen, right-handed. The accelerometer gives specific force including
   gravity (+9.81 m/s² on z for a phone lying face up), the gyroscope angular rate with a
   positive sign counter-clockwise about each axis (right-hand rule), the magnetometer µT.
     Generic Sensor API (Accelerometer, Gyroscope, Magnetometer; referenceFrame "device"):
       acc = (x, y, z) m/s², gyr = (x, y, z) rad/s, mag = (x, y, z) µT: taken as they are.
     DeviceMotionEvent: accelerationIncludingGravity (x, y, z) m/s², the same axes and sign;
       rotationRate in DEGREES per second, alpha about x, beta about y, gamma about z, as
       Chrome, Firefox and Safari give it and the specification says since 2017 (w3c/
       deviceorientation#43; not the Euler-angle order of deviceorientation's alpha, beta,
       gamma): gyr = (alpha, beta, gamma) · π/180 rad/s. Checked in Chromium by
       tests/test_phone_browser.py (a gyroscope override of (0.8, -0.5, 0.25) rad/s reads
       alpha 45.8, beta -28.6, gamma 14.3 deg/s).
   (Safari on iOS has been reported to give accelerationIncludingGravity with the opposite
   sign; ACC_SIGN lets a page flip it, untested here: our tests run Chromium.)

   Time. Every sample is stamped with its event's time on the page's one monotonic clock
   (performance.now() / Event.timeStamp / Sensor.timestamp, ms since the page's time origin),
   in seconds. A sample that does not come after the previous one is dropped and counted:
   the wire wants strictly increasing times.

   Bunched events. A page that was busy (a long task, a garbage collection; a browser that
   queues sensor events rather than coalescing them) gets the events it missed in one burst,
   stamped when they are handled, a fraction of a millisecond apart. The service judges a
   frame's rate by the median interval of its samples (at most 2 kHz: service/protocol/schema.py),
   so a burst that fills half a frame would have the whole frame refused. A sample that comes
   less than MIN_INTERVAL_S after the previous one kept is dropped and counted (`bunched`):
   MIN_INTERVAL_S is half the interval of the fastest browser rate (200 Hz), so no sample of a
   steady stream is ever dropped, and the kept ones are never closer than 400 Hz. */

export const DEG = Math.PI / 180;
export const FRAME_S = 0.1;  // s of samples per wire frame (10 frames a second, like the replay)
export const MAX_FRAME_SAMPLES = 64;  // a frame closes at this many samples whatever their span
export const MIN_INTERVAL_S = 0.0025;  // s: a sample closer to the previous one is a bunched event, dropped
export const MAX_INTERVAL_S = 0.2;  // s: samples further apart go in separate frames (the wire's slowest rate is 5 Hz)

/** A DeviceMotionEvent's reading in SI units and the body frame, or null when it has none. */
export function fromDeviceMotion(ev, accSign = 1) {
  const a = ev.accelerationIncludingGravity, r = ev.rotationRate;
  if (!a || !r || a.x == null || r.alpha == null) return null;
  return {
    t: ev.timeStamp / 1000,
    acc: [accSign * a.x, accSign * a.y, accSign * a.z],
    gyr: [r.alpha * DEG, r.beta * DEG, r.gamma * DEG],
  };
}

/** A Generic Sensor reading (x, y, z, timestamp ms) as [x, y, z]. */
export const xyz = (s) => [s.x, s.y, s.z];

/** Joins the sensors' separate events into samples on the accelerometer's times: each
   accelerometer reading takes the newest gyroscope (and magnetometer) reading before it
   (sample and hold: at 60 Hz a gyro reading is at most one interval old). */
export class SampleJoiner {
  constructor() { this.gyr = null; this.mag = null; }
  gyro(v) { this.gyr = v; }
  magnet(v) { this.mag = v; }
  /** A sample at accelerometer time t (s), or null until the gyroscope has spoken. */
  acc(t, v) {
    if (!this.gyr) return null;
    return {t, acc: v, gyr: this.gyr, mag: this.mag};
  }
}

/** Cuts samples into frames of about FRAME_S: push(sample) returns a finished frame or null
   (a frame may then hold just the new sample, which a later push or flush() sends);
   flush() the frame in progress (a timer calls it when the sensors go quiet). A frame is
   {t, acc, gyr, mag|null}: mag only when every sample of the frame has one. */
export class FrameCutter {
  constructor(frameS = FRAME_S, minIntervalS = MIN_INTERVAL_S) {
    this.frameS = frameS;
    this.minIntervalS = minIntervalS;
    this.lastT = -Infinity;
    this.dropped = 0;  // samples not after their predecessor
    this.bunched = 0;  // samples less than MIN_INTERVAL_S after their predecessor (a burst of late events)
    this.samples = [];
  }

  push(s) {
    if (!(s.t > this.lastT) || ![...s.acc, ...s.gyr].every(Number.isFinite)) { this.dropped++; return null; }
    if (s.t - this.lastT < this.minIntervalS) { this.bunched++; return null; }
    const apart = this.samples.length && s.t - this.lastT > MAX_INTERVAL_S;
    const done = apart ? this.flush() : null;  // a pause in the sensors ends the frame before it
    this.lastT = s.t;
    this.samples.push(s);
    if (done) return done;
    const span = s.t - this.samples[0].t;
    return span >= this.frameS - 1e-9 || this.samples.length >= MAX_FRAME_SAMPLES ? this.flush() : null;
  }

  flush() {
    const ss = this.samples;
    if (!ss.length) return null;
    this.samples = [];
    const withMag = ss.every((s) => s.mag && s.mag.every(Number.isFinite));
    return {t: ss.map((s) => s.t), acc: ss.map((s) => s.acc), gyr: ss.map((s) => s.gyr),
            mag: withMag ? ss.map((s) => s.mag) : null};
  }
}
