// The camera-path panel of the interactive page: keyframes taken from the current view (add,
// set, go to, up, down, delete), the path's duration, frame rate, fov, size and loop flag, play
// at low resolution in the page's canvas, save and load camera_path.json, and the command lines
// that render it. The path's maths and file format are path.ts; main.ts supplies the view and
// the worker (PathHost).

import type { FrameMsg, Intrinsics } from "./protocol";
import {
  type CameraPath, type PathCamera, frameCount, pathCameras, pathIntrinsics, pathText, placementOf, readPath, settingsProblem, verticalFov,
} from "./path";
import { pinhole } from "./camera";

/** Longest side of a played frame: playing previews the path at low resolution. */
export const PREVIEW_SIDE = 160;

/** What the panel needs from the page. */
export interface PathHost {
  scene: any;
  /** The current view's camera-to-world (the field's frame). */
  view(): number[][];
  /** Move the view to a pose (rendered exactly, until moved). */
  goTo(c2w: number[][]): void;
  /** One frame through the render worker; rejects when cancelled (the view moved meanwhile). */
  render(width: number, height: number, c2w: number[][], intrinsics: Intrinsics): Promise<FrameMsg>;
  /** Draw a frame into the page's canvas. */
  show(m: FrameMsg): void;
  /** Render the view again (after playing). */
  resume(): void;
}

/** The rgb of each frame of the last play, when `keep` was set first (for tests). */
export interface PathHook {
  keep: boolean;
  played: { width: number; height: number; rgb: number[] }[];
  /** The keyframes (the field's frame) and settings of the path in the panel. */
  path(): CameraPath;
}

declare global {
  interface Window { nerfPath?: PathHook }
}

/** The preview size of a width × height path: the longer side at most PREVIEW_SIDE, never enlarged. */
export function previewSize(width: number, height: number): [number, number] {
  const k = Math.min(1, PREVIEW_SIDE / Math.max(width, height));
  return [Math.max(1, Math.round(width * k)), Math.max(1, Math.round(height * k))];
}

const $ = <T extends HTMLElement>(id: string) => document.getElementById(id) as T;

export function pathPanel(host: PathHost): void {
  const panel = $("path"), list = $<HTMLSelectElement>("path-keys"), status = $("path-status");
  const input = (id: string) => $<HTMLInputElement>(id);
  const [seconds, fps, fov, width, height, loop] = ["path-seconds", "path-fps", "path-fov", "path-width", "path-height", "path-loop"].map(input);
  const placement = placementOf(host.scene);
  const cam = pinhole(host.scene.camera);
  const keys: PathCamera[] = [];
  seconds.value = "4"; fps.value = "24";
  fov.value = verticalFov(cam.height, cam.fy).toFixed(2); // new keyframes look as the view does
  width.value = String(cam.width); height.value = String(cam.height);
  panel.hidden = false;

  const say = (text: string, state = "idle") => { status.textContent = text; panel.dataset.state = state; };
  const path = (): CameraPath => ({ keyframes: keys, seconds: Number(seconds.value), fps: Number(fps.value),
    width: Number(width.value), height: Number(height.value), loop: loop.checked });
  /** The path, or null with the reason on the panel. */
  const checked = (): CameraPath | null => {
    const p = path(), problem = keys.length ? settingsProblem(p) : "add a keyframe first";
    if (problem) { say(problem, "error"); return null; }
    return p;
  };
  const selected = () => (list.selectedIndex >= 0 ? list.selectedIndex : null);
  const refresh = (select: number | null) => {
    list.replaceChildren(...keys.map((k, i) => new Option(
      `${i + 1}: (${[0, 1, 2].map((a) => k.c2w[a][3].toFixed(2)).join(", ")}) fov ${k.fov.toFixed(1)}°`, String(i))));
    list.selectedIndex = select === null ? -1 : Math.min(select, keys.length - 1);
    const p = path();
    say(`${keys.length} keyframe${keys.length === 1 ? "" : "s"} · ${Number.isFinite(p.seconds * p.fps) ? frameCount(p) : "?"} frames`);
  };
  const fovNow = () => {
    const v = Number(fov.value);
    return v > 0 && v < 180 ? v : null;
  };

  $("path-add").onclick = () => {
    const f = fovNow();
    if (f === null) { say(`fov ${fov.value} is outside (0, 180) degrees`, "error"); return; }
    const at = (selected() ?? keys.length - 1) + 1; // after the selected keyframe
    keys.splice(at, 0, { c2w: host.view().map((r) => [...r]), fov: f });
    refresh(at);
  };
  $("path-set").onclick = () => {
    const i = selected(), f = fovNow();
    if (i === null || f === null) { say(i === null ? "select a keyframe to set" : `fov ${fov.value} is outside (0, 180) degrees`, "error"); return; }
    keys[i] = { c2w: host.view().map((r) => [...r]), fov: f };
    refresh(i);
  };
  $("path-goto").onclick = () => { const i = selected(); if (i !== null) host.goTo(keys[i].c2w); };
  $("path-delete").onclick = () => { const i = selected(); if (i !== null) { keys.splice(i, 1); refresh(keys.length ? Math.max(i - 1, 0) : null); } };
  const swap = (by: number) => {
    const i = selected();
    if (i === null || i + by < 0 || i + by >= keys.length) return;
    [keys[i], keys[i + by]] = [keys[i + by], keys[i]];
    refresh(i + by);
  };
  $("path-up").onclick = () => swap(-1);
  $("path-down").onclick = () => swap(1);
  list.onchange = () => { const i = selected(); if (i !== null) fov.value = String(keys[i].fov); };
  fov.onchange = () => { const i = selected(), f = fovNow(); if (i !== null && f !== null) { keys[i].fov = f; refresh(i); } };
  for (const el of [seconds, fps, width, height, loop]) el.onchange = () => refresh(selected());

  // Play: each camera of camera_path[] in turn, at most one per 1/fps, then the view again.
  let playing = false, stop = false;
  const play = $("path-play");
  play.onclick = async () => {
    if (playing) { stop = true; return; }
    const p = checked();
    if (!p) return;
    const cams = pathCameras(p), [w, h] = previewSize(p.width, p.height);
    const hook = window.nerfPath!;
    hook.played = [];
    playing = true; stop = false; play.textContent = "stop";
    let resume = true;
    try {
      for (let k = 0; k < cams.length && !stop; k++) {
        say(`playing frame ${k + 1} / ${cams.length} at ${w}×${h}`, "playing");
        const due = performance.now() + 1000 / p.fps;
        const m = await host.render(w, h, cams[k].c2w, pathIntrinsics(w, h, cams[k].fov));
        host.show(m);
        if (hook.keep) hook.played.push({ width: m.width, height: m.height, rgb: Array.from(m.rgb) });
        const wait = due - performance.now();
        if (wait > 0) await new Promise((ok) => setTimeout(ok, wait));
      }
      say(stop ? "stopped" : `played ${cams.length} frames at ${w}×${h}`, stop ? "stopped" : "played");
    } catch (e) {
      const message = (e as Error).message;
      resume = message !== "cancelled"; // the view moved: it is rendering already
      say(message === "cancelled" ? "stopped: the view moved" : `play: ${message}`, message === "cancelled" ? "stopped" : "error");
    } finally {
      playing = false; play.textContent = "play";
      if (resume) host.resume();
    }
  };

  $("path-save").onclick = () => {
    const p = checked();
    if (!p) return;
    const a = document.createElement("a");
    a.href = URL.createObjectURL(new Blob([pathText(p, placement)], { type: "application/json" }));
    a.download = "camera_path.json";
    a.click();
    setTimeout(() => URL.revokeObjectURL(a.href), 1000);
    say(`saved camera_path.json: ${keys.length} keyframes, ${frameCount(p)} frames`, "saved");
  };

  const load = input("path-load");
  load.onchange = async () => {
    const file = load.files?.[0];
    load.value = ""; // the same file can be loaded again
    if (!file) return;
    try {
      const p = readPath(await file.text(), file.name, placement);
      keys.splice(0, keys.length, ...p.keyframes);
      seconds.value = String(p.seconds); fps.value = String(p.fps); width.value = String(p.width); height.value = String(p.height);
      loop.checked = p.loop;
      refresh(0);
      fov.value = String(keys[0].fov);
      say(`loaded ${file.name}: ${keys.length} keyframes, ${frameCount(p)} frames`, "loaded");
    } catch (e) { say((e as Error).message, "error"); }
  };

  const command = $("path-command-text");
  $("path-command").onclick = () => {
    command.textContent = "nerf-render --bundle <bundle-dir> --camera-path camera_path.json --out <out-dir>\n" +
      "nerf render --run <run-dir> --camera-path camera_path.json --out <out-dir>";
    command.hidden = !command.hidden;
  };

  window.nerfPath = { keep: false, played: [], path: () => ({ ...path(), keyframes: keys.map((k) => ({ c2w: k.c2w.map((r) => [...r]), fov: k.fov })) }) };
  refresh(null);
}
