// Cross-origin isolation on a static host: onnxruntime-web's threads need SharedArrayBuffer,
// which needs COOP + COEP headers. `nerf-render --serve` sends them; a static host
// (`nerf-render --export-site`) does not, so the page registers our service worker
// (public/isolation-sw.js), which re-serves the site's responses with them, and reloads once.
// Where that cannot work the page runs on one thread and says why.

/** What the page knows when it starts. */
export interface IsolationEnv {
  isolated: boolean; // crossOriginIsolated
  serviceWorker: boolean; // navigator.serviceWorker exists (secure contexts only: https, localhost)
  reloaded: boolean; // this tab already reloaded for the service worker
  off: boolean; // ?sw=0
}

/** Go on (isolated, or on one thread with the reason), or register the worker and reload. */
export type IsolationStep = { step: "go"; why: string | null } | { step: "register" };

export function isolationStep(env: IsolationEnv): IsolationStep {
  if (env.isolated) return { step: "go", why: null };
  if (env.off) return { step: "go", why: "service worker off (?sw=0)" };
  if (!env.serviceWorker) return { step: "go", why: "no service worker: the page is not a secure context (https or localhost)" };
  // Reloaded under the worker and still not isolated: never loop.
  if (env.reloaded) return { step: "go", why: "the service worker did not isolate the page" };
  return { step: "register" };
}

/** The page's own service worker (at the site's root, beside index.html). */
const WORKER = "isolation-sw.js";
const RELOADED = "nerf-isolation-reloaded";

/** Isolates the page if it can. Resolves to null when the page is about to reload (start
 * nothing), else to why it runs on one thread (null when isolated). */
export async function isolate(off: boolean): Promise<{ why: string | null } | null> {
  const env: IsolationEnv = { isolated: crossOriginIsolated, serviceWorker: "serviceWorker" in navigator,
    reloaded: sessionStorage.getItem(RELOADED) === "1", off };
  const step = isolationStep(env);
  if (env.isolated) sessionStorage.removeItem(RELOADED);
  if (step.step === "go") return { why: step.why };
  const sw = navigator.serviceWorker;
  try {
    await sw.register(new URL(WORKER, document.baseURI).href);
    // Once it is active, every navigation of the site (the reload) goes through it.
    await sw.ready;
  } catch (e) {
    return { why: `the service worker did not start: ${(e as Error).message}` };
  }
  sessionStorage.setItem(RELOADED, "1");
  location.reload();
  return null;
}
