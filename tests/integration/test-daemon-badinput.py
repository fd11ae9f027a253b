#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Malformed JSON, wrong types, unknown methods, oversized lines, batches,
half-open connections and a client that does not read: each gets its
documented error (or is dropped), while another client's scan goes on."""
import json
import os
import socket
import time

from daemontest import Client, Daemon, expect, finish, mock_instrument

# The request timeout also bounds the check of a submitted plan (worker
# thread): under valgrind the scanner's plan takes seconds to check.
UNDER_VALGRIND = bool(os.environ.get("ASPH_UNDER_VALGRIND"))
LIMITS = {"max_request_bytes": 65536, "request_timeout_ms": 4000 if UNDER_VALGRIND else 1000,
          "max_output_bytes": 65536}


def raw_exchange(path, data, shutdown=False, timeout=10):
    """Sends bytes, returns every line the daemon answers until it closes
    or goes quiet."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(timeout)
    s.connect(path)
    s.sendall(data)
    if shutdown:
        s.shutdown(socket.SHUT_WR)
    buf = b""
    closed = False
    try:
        while True:
            chunk = s.recv(65536)
            if not chunk:
                closed = True
                break
            buf += chunk
            if not shutdown and buf.endswith(b"\n"):
                s.settimeout(0.3)
    except socket.timeout:
        pass
    s.close()
    return [json.loads(x) for x in buf.split(b"\n") if x], closed


def error_of(lines):
    return lines[0].get("error", {}).get("code") if lines and isinstance(lines[0], dict) else None


d = Daemon(instruments=[mock_instrument(time_factor=0.05)], extra={"limits": LIMITS})
try:
    d.start()
    scanner = Client(d.socket)
    scanner.call("events.subscribe", {"events": ["progress", "job"]})
    job = scanner.call("job.submit", {"lens": "strong", "plan": {"method": "ci", "h": 0.03}})["id"]
    scanner.wait_state(job, ["running"])
    t0 = time.time()

    c = Client(d.socket)
    cases = [
        (b'{"jsonrpc":"2.0","id":1,"method":', -32700, "truncated JSON"),
        (b'{"jsonrpc":"2.0","id":1,"method":"hello"', -32700, "unterminated object"),
        (b'\xff\xfe{"jsonrpc":"2.0"}', -32700, "invalid UTF-8"),
        (b'[' * 5000 + b']' * 5000, -32700, "nesting deeper than the parser allows"),
        (b'{"a":1,"a":2}', -32700, "duplicate keys"),
        (b'[]', -32600, "an empty batch"),
        (b'42', -32600, "a number instead of a request"),
        (b'{"jsonrpc":"1.0","id":1,"method":"hello"}', -32600, "wrong jsonrpc version"),
        (b'{"jsonrpc":"2.0","id":{},"method":"hello"}', -32600, "an object as id"),
        (b'{"jsonrpc":"2.0","id":1,"method":7}', -32600, "a number as method"),
        (b'{"jsonrpc":"2.0","id":1,"method":"hello","extra":1}', -32600, "an unknown member"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.nuke"}', -32601, "an unknown method"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.get","params":{"id":"7"}}', -32602, "a string as job id"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.get","params":{"id":1e400}}', -32700, "a huge number"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.get","params":{"id":-3}}', -32602, "a negative job id"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.get","params":[1]}', -32602, "positional params"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.get","params":{"id":1,"x":0}}', -32602, "an unknown parameter"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.submit","params":{"lens":"strong","plan":{"method":"ci","h":"big"}}}',
         -32602, "a string as plan density"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.submit","params":{"lens":"strong","plan":{"method":"ci","h":0.1,"points":9}}}',
         -32602, "two densities"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.submit","params":{"lens":"strong","plan":{"method":"zigzag","h":0.1}}}',
         106, "an unknown plan method"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.submit","params":{"lens":"../../etc/passwd","plan":{"method":"ci","h":0.1}}}',
         105, "a path as lens is not read"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.submit","params":{"lens":{"type":"even_asphere","R":0},"plan":{"method":"ci","h":0.1}}}',
         105, "an invalid prescription"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.submit","params":{"lens":"strong","plan":{"method":"fermat","points":1e9}}}',
         104, "a plan over the point limit"),
        (b'{"jsonrpc":"2.0","id":1,"method":"job.submit","params":{"lens":"strong","plan":{"method":"ci","h":0.1},"label":"a\\u0000b"}}',
         -32602, "a NUL in a label"),
        (b'{"jsonrpc":"2.0","id":1,"method":"events.subscribe","params":{"events":["everything"]}}', -32602,
         "an unknown event class"),
    ]
    for data, code, what in cases:
        rid = c.next_id = c.next_id + 1
        c.send_raw(data + b"\n")
        m = c.read_message()
        got = m.get("error", {}).get("code") if isinstance(m, dict) else None
        expect(got == code, f"{what}: error {code} (got {got})")
        expect("message" in m.get("error", {}), f"{what}: with a message")
    expect(c.call("version")["server"] == "asphd", "the connection still serves after every error")

    # Batches and notifications.
    c.send_raw(b'[{"jsonrpc":"2.0","id":"a","method":"version"},{"jsonrpc":"2.0","id":"b","method":"nope"},'
               b'{"jsonrpc":"2.0","method":"version"},5]\n')
    batch = c.read_message()
    expect(isinstance(batch, list) and len(batch) == 3, "a batch: one response per request, none for the notification")
    ids = {r.get("id"): r for r in batch}
    expect("result" in ids.get("a", {}) and ids.get("b", {}).get("error", {}).get("code") == -32601
           and ids.get(None, {}).get("error", {}).get("code") == -32600, "each batch element answered on its own")
    c.send_raw(b'{"jsonrpc":"2.0","method":"daemon.status"}\n[{"jsonrpc":"2.0","method":"version"}]\n')
    expect(c.call("version")["server"] == "asphd", "notifications get no response")

    # Oversized lines: refused, and the connection goes on.
    c.send_raw(b'{"jsonrpc":"2.0","id":1,"method":"hello","params":{"client":"' + b"x" * 200000 + b'"}}\n')
    expect(c.read_message()["error"]["code"] == -32000, "a line over the limit: -32000")
    expect(c.call("version")["server"] == "asphd", "the next request on that connection is served")

    # Half-open connections.
    lines, closed = raw_exchange(d.socket, b'{"jsonrpc":"2.0","id":9,', shutdown=True)
    expect(error_of(lines) == -32700 and closed, "input ends inside a request: -32700, then closed")
    lines, closed = raw_exchange(d.socket, b'{"jsonrpc":"2.0","id":9,"method":"version"}\n', shutdown=True)
    expect(lines and lines[0].get("result") and closed, "a request then end of input: answered, then closed")
    lines, closed = raw_exchange(d.socket, b'{"jsonrpc":"2.0","id":9,"meth',
                                 timeout=LIMITS["request_timeout_ms"] / 1000 + 5)
    expect(error_of(lines) == -32003, "an incomplete request that stalls: -32003")

    # A client that never reads its output is dropped, not waited for.
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.connect(d.socket)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.settimeout(5)
    req = b'{"jsonrpc":"2.0","id":1,"method":"instrument.list"}\n' * 200
    dropped = False
    t_slow = time.time()
    try:
        for _ in range(2000):
            s.sendall(req)
    except (BrokenPipeError, ConnectionResetError):
        dropped = True
    except socket.timeout:
        dropped = False
    s.close()
    expect(dropped, f"a client that does not read is dropped ({time.time() - t_slow:.2f} s)")
    expect("does not read its output" in d.log_text(), "the log says why")

    # Meanwhile the scan went on.
    st = scanner.call("job.get", {"id": job})
    expect(st["state"] in ("running", "completed") and st["progress"]["done"] > 0, "the scan ran during all this")
    end = scanner.wait_state(job, ["completed", "failed", "cancelled"])
    expect(end == "completed", f"and completed ({end}) after {time.time() - t0:.1f} s")
    expect(scanner.call("daemon.status")["clients"] >= 1, "daemon.status answers")
    scanner.close()
    c.close()
    expect(d.stop() == 0, "clean stop")
except Exception:
    print(d.log_text())
    raise
finally:
    d.cleanup()
finish()
