// The viewer's service worker for static hosts (nerf-render --export-site): such hosts send no
// cross-origin isolation headers, and onnxruntime-web's threads need SharedArrayBuffer, which
// needs them. This worker passes each of the site's own requests to the network and answers
// with the same response plus COOP/COEP/CORP, so the page it controls is isolated. The page
// registers it only when it is not isolated already (src/isolation.ts) and reloads once.
self.addEventListener("install", () => self.skipWaiting());
// Take the open page at once, so that its one reload comes back through this worker.
self.addEventListener("activate", (event) => event.waitUntil(self.clients.claim()));

/** `response` with the isolation headers added (opaque and error responses as they are). */
function isolated(response) {
  if (response.type === "opaque" || response.type === "opaqueredirect" || response.status === 0) return response;
  const headers = new Headers(response.headers);
  headers.set("Cross-Origin-Opener-Policy", "same-origin");
  headers.set("Cross-Origin-Embedder-Policy", "require-corp");
  headers.set("Cross-Origin-Resource-Policy", "same-origin");
  return new Response(response.body, { status: response.status, statusText: response.statusText, headers });
}

self.addEventListener("fetch", (event) => {
  const request = event.request;
  // Only the site's own files; anything else goes to the network untouched.
  if (new URL(request.url).origin !== self.location.origin) return;
  // Chromium refuses to fetch this combination from a worker (a devtools quirk).
  if (request.cache === "only-if-cached" && request.mode !== "same-origin") return;
  event.respondWith(fetch(request).then(isolated));
});
