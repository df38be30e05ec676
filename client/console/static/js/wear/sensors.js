/* Where the phone's samples come from: the Generic Sensor API when the browser has it and
   lets the page use it, DeviceMotionEvent otherwise; the position from the Geolocation API;
   the screen kept on by a wake lock. Conversions are in motion.js. */
import {SampleJoiner, fromDeviceMotion, xyz} from "./motion.js";

export const SENSOR_HZ = 60;  // what we ask for (Chromium caps motion sensors at 60 Hz)

/** Start the motion sensors; onSample({t, acc, gyr, mag}) for each sample. Resolves to
   {api: "generic" | "devicemotion", magnetometer: bool, stop()}, or rejects saying why none works. */
export async function startMotion(onSample, onProblem) {
  if (window.Accelerometer && window.Gyroscope) {
    try {
      return await startGeneric(onSample, onProblem);
    } catch (e) {
      onProblem(`Generic Sensor API unavailable (${e.name || e}): using device motion events`);
    }
  }
  if (!window.DeviceMotionEvent) throw new Error("this browser gives no motion sensors to web pages");
  if (typeof DeviceMotionEvent.requestPermission === "function") {  // iOS: a tap must ask
    const answer = await DeviceMotionEvent.requestPermission();
    if (answer !== "granted") throw new Error("motion sensors: permission refused");
  }
  const handler = (ev) => { const s = fromDeviceMotion(ev); if (s) onSample({...s, mag: null}); };
  window.addEventListener("devicemotion", handler);
  return {api: "devicemotion", magnetometer: false, stop: () => window.removeEventListener("devicemotion", handler)};
}

function started(sensor) {
  return new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error(`${sensor.constructor.name}: no reading within 3 s`)), 3000);
    sensor.addEventListener("reading", () => { clearTimeout(timer); resolve(); }, {once: true});
    sensor.addEventListener("error", (e) => { clearTimeout(timer); reject(e.error); }, {once: true});
    sensor.start();
  });
}

async function startGeneric(onSample, onProblem) {
  const opts = {frequency: SENSOR_HZ, referenceFrame: "device"};
  const acc = new Accelerometer(opts), gyr = new Gyroscope(opts);
  const join = new SampleJoiner();
  gyr.addEventListener("reading", () => join.gyro(xyz(gyr)));
  acc.addEventListener("reading", () => {
    const s = join.acc(acc.timestamp / 1000, xyz(acc));
    if (s) onSample(s);
  });
  const sensors = [acc, gyr];
  await Promise.all([started(gyr), started(acc)]);
  let magnetometer = false;
  if (window.Magnetometer) {
    try {
      const mag = new Magnetometer(opts);
      mag.addEventListener("reading", () => join.magnet(xyz(mag)));
      await started(mag);
      sensors.push(mag);
      magnetometer = true;
    } catch (e) {
      onProblem(`no magnetometer (${e.name || e}): heading from the gyroscope alone`);
    }
  }
  for (const s of sensors) s.addEventListener("error", (e) => onProblem(`${s.constructor.name}: ${e.error.message}`));
  return {api: "generic", magnetometer, stop: () => sensors.forEach((s) => s.stop())};
}

/** Watch the position: onFix({t, lat, lon, accuracy}) on the page's clock (s). */
export function watchPosition(onFix, onProblem) {
  if (!navigator.geolocation) { onProblem("no geolocation in this browser"); return () => {}; }
  const id = navigator.geolocation.watchPosition(
    (p) => onFix({t: (p.timestamp - performance.timeOrigin) / 1000, lat: p.coords.latitude,
                  lon: p.coords.longitude, accuracy: p.coords.accuracy}),
    (e) => onProblem(`position: ${e.message || e.code}`),
    {enableHighAccuracy: true, maximumAge: 0});
  return () => navigator.geolocation.clearWatch(id);
}

/** Keep the screen on while tracking (re-taken when the page is shown again). */
export class ScreenLock {
  constructor() { this.lock = null; this.wanted = false; }
  async take() {
    this.wanted = true;
    if (!navigator.wakeLock || document.visibilityState !== "visible") return false;
    try {
      this.lock = await navigator.wakeLock.request("screen");
      this.lock.addEventListener("release", () => { this.lock = null; });
      return true;
    } catch (e) {
      return false;
    }
  }
  release() { this.wanted = false; if (this.lock) this.lock.release(); }
  get held() { return !!this.lock; }
}
