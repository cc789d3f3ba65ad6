// The service's /v1 API as seen from the page: one fetch wrapper that adds the API key (kept in this
// module's memory only, never in storage) and turns the service's error body into an exception.

let apiKey = "";

/** Set the key sent as X-API-Key ("" sends none). */
export function setApiKey(key) {
  apiKey = key.trim();
}

/** Whether a key is set. */
export function hasApiKey() {
  return apiKey !== "";
}

/** An API path ("v1/maps") as an absolute URL, relative to the page (works behind a path prefix). */
export function apiUrl(path) {
  return new URL(path.replace(/^\//, ""), document.baseURI).href;
}

/** An error answered by the service: HTTP status, machine code and human message. */
export class ApiError extends Error {
  constructor(status, code, message, details) {
    super(message);
    this.status = status;
    this.code = code;
    this.details = details;
  }
}

/** fetch() an API path with the key; resolves to the Response, rejects with ApiError on 4xx/5xx. */
export async function request(path, options = {}) {
  const headers = new Headers(options.headers || {});
  if (apiKey) headers.set("X-API-Key", apiKey);
  let response;
  try {
    response = await fetch(apiUrl(path), { ...options, headers });
  } catch (err) {
    throw new ApiError(0, "network", `the service cannot be reached (${err.message})`);
  }
  if (!response.ok) {
    let code = "error";
    let message = `${response.status} ${response.statusText}`;
    let details;
    try {
      const body = await response.json();
      if (body && body.error) ({ code, message, details } = body.error);
    } catch {
      // not JSON: keep the status line
    }
    throw new ApiError(response.status, code, message, details);
  }
  return response;
}

/** GET (or other method) returning parsed JSON. */
export async function getJson(path, options = {}) {
  const response = await request(path, options);
  return response.json();
}

/** POST a multipart form; resolves to {status, body}. */
export async function postForm(path, formData) {
  const response = await request(path, { method: "POST", body: formData });
  return { status: response.status, body: await response.json() };
}

/** A binary resource (photo, PNG) as an object URL usable in <img> (an <img> cannot send the key). */
export async function objectUrl(path) {
  const response = await request(path);
  return URL.createObjectURL(await response.blob());
}
