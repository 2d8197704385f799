#!/usr/bin/env python3
"""A loopback HTTP server for the remote-store tests: serves a folder over GET and HEAD with
Range requests (206 + Content-Range, 416 when unsatisfiable, 404 for a missing file), HTTP/1.1
keep-alive, and fault injection. Standard library only.

    range_server.py ROOT            prints "PORT <n>" on its first stdout line, then serves

The first path segment of every request chooses how the objects below it are served
(``/MODE/REST`` serves ``ROOT/REST``). Faults hit chunk objects only: metadata documents
(``zarr.json``, ``.zarray``, ``.zattrs``, ``.zgroup``) are always served normally, except under
``meta500``.

    ok        normal
    500       every chunk request answers 500 Internal Server Error
    500once   the first request for each chunk answers 500, later ones are served
    stall     chunk responses send their headers, then stall (no body) for 60 s
    truncate  chunk responses declare the full Content-Length, send half the body and close
    longlen   chunk responses declare 16 bytes more than the body, send it and close
    corrupt   chunk objects are served whole and well-formed (status, length), but as their first
              half only: a body that arrives intact and does not decode
    meta500   metadata requests answer 500 (chunks are served)
    slow      chunk responses wait 20 ms before answering (an object store's latency)

With MIXVOL_RANGE_SERVER_LOG set, every request is logged to stderr.

``MODE@KEY`` applies the fault MODE to one object only: the one whose path ends with KEY, with
``~`` for ``/`` (``500@0~c~1~0~2`` fails chunk ``0/c/1/0/2`` with 500 and serves the rest).

``GET /_count/MODE/REST`` answers the number of requests seen so far for ``/MODE/REST`` (any
method), as text.
"""

import http.server
import os
import sys
import threading
import time

METADATA = {"zarr.json", ".zarray", ".zattrs", ".zgroup"}
MODES = {"ok", "500", "500once", "stall", "truncate", "longlen", "meta500", "slow", "corrupt"}

counts = {}
counts_lock = threading.Lock()


class Handler(http.server.BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    # TCP_NODELAY: headers and body go out as separate writes, and Nagle's algorithm would hold
    # the body until the client's delayed ACK (about 40 ms a request on loopback).
    disable_nagle_algorithm = True
    root = "."

    def log_message(self, format, *args):
        # Quiet unless MIXVOL_RANGE_SERVER_LOG is set (then to stderr; stdout carries the port).
        if os.environ.get("MIXVOL_RANGE_SERVER_LOG"):
            sys.stderr.write(f"range_server: {format % args} [{self.headers.get('Range')}]\n")

    def do_HEAD(self):
        self.serve(head=True)

    def do_GET(self):
        if self.path.startswith("/_count/"):
            target = self.path[len("/_count"):]
            with counts_lock:
                body = str(counts.get(target, 0)).encode()
            self.send_response(200)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
            return
        self.serve(head=False)

    def plain(self, status, text=b""):
        self.send_response(status)
        self.send_header("Content-Length", str(len(text)))
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(text)

    def serve(self, head):
        path = self.path.split("?", 1)[0]
        with counts_lock:
            counts[path] = counts.get(path, 0) + 1
            seen = counts[path]
        parts = [p for p in path.split("/") if p]
        if not parts or parts[0].partition("@")[0] not in MODES or any(
            p in (".", "..") for p in parts
        ):
            self.plain(404, b"not found")
            return
        mode, rest = parts[0], parts[1:]
        is_meta = bool(rest) and rest[-1] in METADATA
        if "@" in mode:
            mode, _, target = mode.partition("@")
            if not "/".join(rest).endswith(target.replace("~", "/")):
                mode = "ok"
        if mode == "meta500" and is_meta or mode == "500" and not is_meta:
            self.plain(500, b"injected failure")
            return
        if mode == "500once" and not is_meta and seen == 1:
            self.plain(500, b"injected failure (once)")
            return
        if mode == "slow" and not is_meta:
            time.sleep(0.02)
        file = os.path.join(self.root, *rest)
        if not os.path.isfile(file):
            self.plain(404, b"not found")
            return
        with open(file, "rb") as f:
            data = f.read()
        if mode == "corrupt" and not is_meta:
            data = data[: len(data) // 2]
        size = len(data)
        status, start, end = 200, 0, size
        rng = self.headers.get("Range")
        if rng:
            parsed = parse_range(rng, size)
            if parsed is None:
                self.send_response(416)
                self.send_header("Content-Range", f"bytes */{size}")
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
            status, (start, end) = 206, parsed
        body = data[start:end]
        fault = None if is_meta else mode
        self.send_response(status)
        self.send_header("Accept-Ranges", "bytes")
        if status == 206:
            self.send_header("Content-Range", f"bytes {start}-{end - 1}/{size}")
        declared = len(body) + (16 if fault == "longlen" else 0)
        self.send_header("Content-Length", str(declared))
        if fault in ("truncate", "longlen"):
            self.send_header("Connection", "close")
        self.end_headers()
        if head:
            return
        if fault == "stall":
            self.wfile.flush()
            time.sleep(60)
            self.close_connection = True
            return
        if fault == "truncate":
            self.wfile.write(body[: len(body) // 2])
            self.wfile.flush()
            self.close_connection = True
            return
        self.wfile.write(body)
        if fault == "longlen":
            self.wfile.flush()
            self.close_connection = True


def parse_range(header, size):
    """(start, end) for a single `bytes=` range, or None when unsatisfiable."""
    if not header.startswith("bytes=") or "," in header:
        return None
    first, _, last = header[len("bytes="):].strip().partition("-")
    try:
        if first == "":
            n = int(last)
            if n <= 0:
                return None
            return max(0, size - n), size
        start = int(first)
        end = int(last) + 1 if last else size
    except ValueError:
        return None
    end = min(end, size)
    if start >= size or start >= end:
        return None
    return start, end


def main():
    if len(sys.argv) != 2 or not os.path.isdir(sys.argv[1]):
        sys.exit("usage: range_server.py ROOT_FOLDER")
    Handler.root = sys.argv[1]
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    server.daemon_threads = True
    print(f"PORT {server.server_address[1]}", flush=True)
    server.serve_forever()


if __name__ == "__main__":
    main()
