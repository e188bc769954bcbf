"""Hostile traffic against a running `gatewatch serve`, the reproductions of stop 97's review
(docs/benchmarks.md, "Stop 97: what two reviews of the shipped binary found"). Standard library
only. The daemon's configuration there: `request_timeout_seconds = 10`, `max_gates = 64`,
`tcp_idle_timeout_seconds = 20`, `worker_threads = 1`, loopback listeners; read its peak memory
with `grep VmHWM /proc/PID/status` after a run.

    python3 benches/python/hostile_ingest.py late-body  [--http 127.0.0.1:9464] [--timeout 10]
    python3 benches/python/hostile_ingest.py late-gates [--http ...] [--timeout 10]
    python3 benches/python/hostile_ingest.py gates      [--http ...] [--clients 6] [--rounds 3]
    python3 benches/python/hostile_ingest.py tcp-idle   [--tcp 127.0.0.1:8094] [--http ...]

- `late-body`: 85,000 lines of one gate (3.6 MB), all but the last 10 bytes at once, those 10
  bytes 0.3 ... 0.01 s before the request timeout; prints each answer and the samples the gate
  holds then (a 408 must come with none of them).
- `late-gates`: four 4.15 MB bodies whose every line names another gate, finishing 0.03 s before
  the timeout, and four more at the timeout (the admission bound must hold meanwhile).
- `gates`: `--clients` concurrent 4.19 MB bodies of 209,501 gates, `--rounds` times.
- `tcp-idle`: a connection that sends nothing, one that sends half a line at once, one that sends
  half a line after 15 s; prints when each was closed.
"""
import argparse
import itertools
import json
import socket
import string
import threading
import time
import urllib.request


def addr(s):
    host, port = s.rsplit(":", 1)
    return host, int(port)


def post(http, path, body, timeout=60, send=None):
    """POST `body` and return the raw answer; `send(sock, head, body)` may pace the bytes."""
    s = socket.create_connection(http, timeout=timeout)
    head = (f"POST {path} HTTP/1.1\r\nHost: x\r\nContent-Type: text/plain\r\n"
            f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n").encode()
    if send is None:
        s.sendall(head + body)
    else:
        send(s, head, body)
    out = b""
    try:
        while True:
            b = s.recv(65536)
            if not b:
                break
            out += b
    except OSError as e:
        out += f"<<{e}>>".encode()
    s.close()
    return out


def samples_total(http, gate):
    try:
        with urllib.request.urlopen(f"http://{http[0]}:{http[1]}/api/v1/gates/{gate}") as r:
            return json.load(r)["window"]["samples_total"]
    except Exception as e:  # noqa: BLE001 (a 404 is an answer here)
        return str(e)


def many_gates(size):
    alphabet = string.ascii_lowercase + string.digits
    lines, n = [], 0
    for t in itertools.product(alphabet, repeat=4):
        line = f"m,gate={''.join(t)} force=0\n"
        n += len(line)
        lines.append(line)
        if n > size:
            break
    return "".join(lines).encode()


def late_body(a):
    t0 = (int(time.time()) - 2000) * 10**9
    for k, early in enumerate([0.3, 0.2, 0.15, 0.1, 0.07, 0.05, 0.03, 0.01]):
        gate = f"L{k}{int(time.time()) % 1000:03d}"  # short: 85,000 lines stay under 4 MiB
        body = "".join(f"m,gate={gate} force={i % 100}.25 {t0 + i * 5_000_000}\n" for i in range(85_000)).encode()

        def send(s, head, body, early=early):
            s.sendall(head)
            start = time.time()
            s.sendall(body[:-10])
            time.sleep(max(0.0, a.timeout - early - (time.time() - start)))
            s.sendall(body[-10:])

        began = time.time()
        answer = post(a.http, "/api/v2/write", body, send=send)
        took = time.time() - began
        time.sleep(1.0)  # work the answer did not wait for lands meanwhile
        status = answer.split(b"\r\n")[0].decode()
        print(f"last bytes {early:.2f} s early: {status} after {took:.2f} s; "
              f"samples of the gate: {samples_total(a.http, gate)}")


def late_gates(a):
    body = many_gates(4_150_000)
    results = {}

    def one(i, late):
        def send(s, head, body):
            s.sendall(head)
            start = time.time()
            s.sendall(body[:-5])
            if late:
                time.sleep(max(0.0, a.timeout - 0.03 - (time.time() - start)))
            s.sendall(body[-5:])

        began = time.time()
        answer = post(a.http, "/api/v2/write", body, send=send)
        results[i] = (round(time.time() - began, 2), answer.split(b"\r\n")[0].decode())

    first = [threading.Thread(target=one, args=(i, True)) for i in range(4)]
    [t.start() for t in first]
    time.sleep(a.timeout)
    second = [threading.Thread(target=one, args=(10 + i, False)) for i in range(4)]
    [t.start() for t in second]
    [t.join() for t in first + second]
    for k in sorted(results):
        print(k, results[k])


def gates(a):
    body = many_gates(4_190_000)
    lines = body.count(b"\n")
    print(f"body {len(body)} bytes, {lines} gates")
    for r in range(a.rounds):
        answers = []

        def one():
            answers.append(post(a.http, "/api/v2/write", body).split(b"\r\n")[0].decode())

        threads = [threading.Thread(target=one) for _ in range(a.clients)]
        [t.start() for t in threads]
        [t.join() for t in threads]
        print(f"round {r}: {sorted(answers)}")


def tcp_idle(a):
    for label, payload, after in [("nothing sent", b"", 0),
                                  ("half a line at once", b"m,gate=idle force=1", 0),
                                  ("half a line after 15 s", b"m,gate=idle force=1", 15)]:
        s = socket.create_connection(a.tcp, timeout=120)
        began = time.time()
        if after:
            time.sleep(after)
        if payload:
            s.sendall(payload)
        try:
            s.recv(10)
            print(f"{label}: closed after {time.time() - began:.1f} s")
        except OSError as e:
            print(f"{label}: {e} after {time.time() - began:.1f} s")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", choices=["late-body", "late-gates", "gates", "tcp-idle"])
    p.add_argument("--http", type=addr, default=addr("127.0.0.1:9464"))
    p.add_argument("--tcp", type=addr, default=addr("127.0.0.1:8094"))
    p.add_argument("--timeout", type=float, default=10.0, help="the daemon's request_timeout_seconds")
    p.add_argument("--clients", type=int, default=6)
    p.add_argument("--rounds", type=int, default=3)
    a = p.parse_args()
    {"late-body": late_body, "late-gates": late_gates, "gates": gates, "tcp-idle": tcp_idle}[a.what](a)


if __name__ == "__main__":
    main()
