// The service's /v1 API as the pages use it. A service started with an API key wants it on
// every call: the pages ask for it once and keep it in this browser's localStorage.

const KEY = "inssplat-api-key";

function headers(extra = {}) {
  const key = localStorage.getItem(KEY);
  return key ? { ...extra, Authorization: `Bearer ${key}` } : extra;
}

/** The error message of a non-2xx answer (the service's `{error, error_type}` shape). */
async function failure(response) {
  let message = `${response.status} ${response.statusText}`;
  try {
    message = (await response.json()).error ?? message;
  } catch {}
  if (response.status === 401) {
    const key = prompt("This service needs its API key:");
    if (key) localStorage.setItem(KEY, key);
  }
  return new Error(message);
}

export async function getJson(url) {
  const response = await fetch(url, { headers: headers() });
  if (!response.ok) throw await failure(response);
  return response.json();
}

export async function postJson(url, body) {
  const response = await fetch(url, { method: "POST", headers: headers({ "Content-Type": "application/json" }), body: JSON.stringify(body) });
  if (!response.ok) throw await failure(response);
  return response.json();
}

export async function getBytes(url) {
  const response = await fetch(url, { headers: headers() });
  if (!response.ok) throw await failure(response);
  return response.arrayBuffer();
}

/** POSTs `form` and resolves to the JSON answer; `onUpload(fraction)` follows the upload. */
export function postForm(url, form, onUpload) {
  return new Promise((resolve, reject) => {
    const xhr = new XMLHttpRequest();
    xhr.open("POST", url);
    for (const [k, v] of Object.entries(headers())) xhr.setRequestHeader(k, v);
    xhr.upload.onprogress = (e) => e.lengthComputable && onUpload(e.loaded / e.total);
    xhr.upload.onload = () => onUpload(1);
    xhr.onerror = () => reject(new Error("the service cannot be reached"));
    xhr.onload = () => {
      const response = new Response(xhr.response, { status: xhr.status, statusText: xhr.statusText });
      if (xhr.status >= 200 && xhr.status < 300) resolve(response.json());
      else failure(response).then(reject);
    };
    xhr.send(form);
  });
}

const FINISHED = ["done", "failed", "cancelled"];

/** Follows a job: `onStatus(JobStatus)` on each change, from its server-sent events (or by
 * polling, where EventSource cannot send the API key), until the job has ended. */
export function followJob(id, onStatus, onError) {
  const source = new EventSource(`/v1/jobs/${id}/events`);
  source.addEventListener("status", (e) => onStatus(JSON.parse(e.data)));
  source.onerror = () => {
    source.close();
    const poll = () =>
      getJson(`/v1/jobs/${id}`).then((status) => {
        onStatus(status);
        if (!FINISHED.includes(status.state)) setTimeout(poll, 2000);
      }, onError);
    poll();
  };
}
