// Live training (`nerf train --serve`, `nerf view RUN`): the server's live/status.json says which
// snapshot of the field is the newest (live/<id>/, a bundle) and how the run is going. This
// module polls it, shows the progress and the PSNR curve, and asks the page to load each new
// snapshot; the page keeps the user's camera and renders again only then (no render loop: the
// page's renders share the machine with the trainer).

/** progress.json as the trainer writes it (src/live.rs). */
export interface Progress {
  step: number; iters: number; elapsed_s: number; budget_s: number | null; remaining_s: number | null;
  steps_per_s: number; loss: number | null; train_psnr: number; val_psnr: number | null; snapshots: boolean; done: boolean;
}
/** A row of the run's curve.csv. */
export interface CurveRow { step: number; minutes: number; train_psnr: number; val_psnr: number | null }
export interface LiveStatus {
  snapshot: string | null; progress: Progress | null; progress_age_s: number | null; curve: CurveRow[]; note: string | null;
}

/** How often the status is asked for. */
export const POLL_MS = 2000;
/** The live view's width: a sixteenth of the pixels of a 400-wide view, so that rendering each
 *  snapshot takes little from the trainer on the same machine (?width= overrides). */
export const LIVE_WIDTH = 100;
/** The most field samples of a live pass the view refines to: early in training the occupancy
 *  grid is still full and nothing stops a ray (lego at 5 s: about 1,400 samples a ray, where a
 *  trained field takes 18), so a live view stays coarse until the field sparsens. A trained
 *  lego's 100×100 view takes 176,693. */
export const LIVE_POINTS = 200_000;
/** A progress.json older than this (seconds) is a trainer that stopped without finishing. */
const STALE_S = 30;

/** The status of the server the page came from, or null when it is not live (nerf-render
 *  --serve, a static host). */
export async function probeLive(base: string): Promise<LiveStatus | null> {
  try {
    const res = await fetch(new URL("live/status.json", base), { cache: "no-store" });
    return res.ok ? ((await res.json()) as LiveStatus) : null;
  } catch { return null; }
}

/** "12 s", "4 min 05 s", "1 h 02 min". */
export function duration(seconds: number): string {
  const s = Math.max(0, Math.round(seconds));
  if (s < 60) return `${s} s`;
  const m = Math.floor(s / 60);
  if (m < 60) return `${m} min ${String(s % 60).padStart(2, "0")} s`;
  return `${Math.floor(m / 60)} h ${String(m % 60).padStart(2, "0")} min`;
}

/** One line of what the run is doing, e.g. "step 1,200 / 100,000 · 2 min 40 s trained ·
 *  7 min 20 s left · loss 0.0042 · train 24.51 dB · val 26.10 dB". */
export function progressLine(st: LiveStatus): string {
  const p = st.progress;
  if (!p) return st.note ?? "no progress recorded yet";
  const parts = [`step ${p.step.toLocaleString("en")} / ${p.iters.toLocaleString("en")}`, `${duration(p.elapsed_s)} trained`];
  if (p.done) parts.push("done");
  else if (st.progress_age_s !== null && st.progress_age_s > STALE_S) parts.push(`not training (last update ${duration(st.progress_age_s)} ago)`);
  else if (p.remaining_s !== null) parts.push(`${duration(p.remaining_s)} left`);
  if (p.loss !== null) parts.push(`loss ${p.loss.toFixed(4)}`);
  parts.push(`train ${p.train_psnr.toFixed(2)} dB`);
  if (p.val_psnr !== null) parts.push(`val ${p.val_psnr.toFixed(2)} dB`);
  return parts.join(" · ") + (st.note ? ` · ${st.note}` : "");
}

/** The curve as canvas points: val and train PSNR against minutes, scaled into w×h with a
 *  margin `pad`; `range` is the PSNR span drawn (dB). */
export function curvePoints(rows: CurveRow[], w: number, h: number, pad = 4): { train: number[][]; val: number[][]; range: [number, number] } {
  const values = rows.flatMap((r) => [r.train_psnr, ...(r.val_psnr === null ? [] : [r.val_psnr])]).filter(Number.isFinite);
  if (!rows.length || !values.length) return { train: [], val: [], range: [0, 0] };
  let lo = Math.floor(Math.min(...values)), hi = Math.ceil(Math.max(...values));
  if (hi <= lo) hi = lo + 1;
  const t1 = Math.max(...rows.map((r) => r.minutes)), t0 = Math.min(...rows.map((r) => r.minutes));
  const x = (t: number) => pad + (t1 > t0 ? (t - t0) / (t1 - t0) : 0.5) * (w - 2 * pad);
  const y = (v: number) => h - pad - ((v - lo) / (hi - lo)) * (h - 2 * pad);
  return {
    train: rows.filter((r) => Number.isFinite(r.train_psnr)).map((r) => [x(r.minutes), y(r.train_psnr)]),
    val: rows.filter((r) => r.val_psnr !== null).map((r) => [x(r.minutes), y(r.val_psnr!)]),
    range: [lo, hi],
  };
}

function drawCurve(canvas: HTMLCanvasElement, rows: CurveRow[]): void {
  const ctx = canvas.getContext("2d")!;
  const { width: w, height: h } = canvas;
  ctx.clearRect(0, 0, w, h);
  const { train, val, range } = curvePoints(rows, w, h);
  const line = (points: number[][], colour: string, dash: number[]) => {
    if (!points.length) return;
    ctx.strokeStyle = ctx.fillStyle = colour; ctx.setLineDash(dash); ctx.beginPath();
    points.forEach(([x, y], i) => (i ? ctx.lineTo(x, y) : ctx.moveTo(x, y)));
    ctx.stroke();
    for (const [x, y] of points) ctx.fillRect(x - 1.5, y - 1.5, 3, 3);
  };
  line(train, "#8ab4f8", [4, 3]);
  line(val, "#f6c343", []);
  ctx.setLineDash([]); ctx.fillStyle = "#aaa"; ctx.font = "10px sans-serif";
  ctx.fillText(train.length ? `${range[1]} dB` : "PSNR curve: none yet", 2, 10);
  if (train.length) ctx.fillText(`${range[0]} dB · val solid, train dashed`, 2, h - 2);
}

declare global {
  interface Window {
    /** The live view's state, for tests: the snapshot shown, the step the status reports, and
     *  how many snapshots were loaded. */
    nerfLive?: { snapshot: string | null; step: number | null; loads: number; askedAt: number; loadedAt: number };
  }
}

/** What the page does for the live view. */
export interface LiveHooks {
  /** Load the bundle at `url` into the worker; the page then calls `loaded()` or `failed()`. */
  load(url: string): void;
  /** Training has ended and its last snapshot is shown: the machine is the page's again. */
  finished(): void;
}

/** Start the live view from the first status: show the panel, poll, and load each new snapshot
 *  (one load at a time; one that fails is tried again only once the status names another). */
export function startLive(base: string, first: LiveStatus, hooks: LiveHooks): { loaded(): void; failed(message: string): void } {
  const panel = document.getElementById("live")!, text = document.getElementById("live-progress")!;
  const curve = document.getElementById("live-curve") as HTMLCanvasElement;
  panel.hidden = false;
  document.body.classList.add("live");
  // askedAt, loadedAt: when the latest snapshot was asked for and was loaded (performance.now()).
  const state = (window.nerfLive = { snapshot: null as string | null, step: null as number | null, loads: 0, askedAt: 0, loadedAt: 0 });
  let asked: string | null = null, failed: string | null = null, problem: string | null = null, ended = false;
  const show = (st: LiveStatus) => {
    state.step = st.progress?.step ?? null;
    text.textContent = progressLine(st) + (problem ? ` · ${problem}` : "") + (st.snapshot ? "" : " · waiting for the first snapshot");
    // curve.csv has a row per validation; the trainer's latest point goes on its end.
    const p = st.progress, lastStep = st.curve.at(-1)?.step ?? -1;
    drawCurve(curve, p && p.step > lastStep ? [...st.curve, { step: p.step, minutes: p.elapsed_s / 60, train_psnr: p.train_psnr, val_psnr: null }] : st.curve);
    // A hidden page loads nothing (it would render for no one); it catches up once shown.
    if (st.snapshot && st.snapshot !== state.snapshot && st.snapshot !== asked && st.snapshot !== failed && asked === null && !document.hidden) {
      asked = st.snapshot;
      state.askedAt = performance.now();
      hooks.load(new URL(`live/${st.snapshot}/`, base).href);
    }
    if (!ended && st.progress?.done && st.snapshot !== null && st.snapshot === state.snapshot) {
      ended = true;
      hooks.finished();
    }
  };
  const poll = async () => {
    const st = await probeLive(base);
    if (st) show(st);
    else text.textContent = "the server does not answer (training stopped?)";
    setTimeout(poll, POLL_MS);
  };
  show(first);
  setTimeout(poll, POLL_MS);
  return {
    loaded() { state.snapshot = asked; state.loads++; state.loadedAt = performance.now(); asked = null; problem = null; },
    failed(message) { failed = asked; asked = null; problem = `snapshot not loaded: ${message}`; },
  };
}
