// The page's choice about cross-origin isolation (src/isolation.ts): register the service
// worker at most once a tab, never when isolated already, and say why it runs on one thread.
import { describe, expect, it } from "vitest";
import { isolationStep } from "../../src/isolation";

const env = { isolated: false, serviceWorker: true, reloaded: false, off: false };

describe("isolationStep", () => {
  it("registers the worker on a static host, once", () => {
    expect(isolationStep(env)).toEqual({ step: "register" });
    expect(isolationStep({ ...env, reloaded: true })).toEqual({ step: "go", why: "the service worker did not isolate the page" });
  });
  it("goes on without it when the headers are there", () => {
    expect(isolationStep({ ...env, isolated: true })).toEqual({ step: "go", why: null });
    expect(isolationStep({ ...env, isolated: true, reloaded: true, off: true })).toEqual({ step: "go", why: null });
  });
  it("says why it runs on one thread", () => {
    expect(isolationStep({ ...env, off: true })).toEqual({ step: "go", why: "service worker off (?sw=0)" });
    expect(isolationStep({ ...env, serviceWorker: false })).toMatchObject({ step: "go", why: expect.stringMatching(/not a secure context/) });
  });
});
