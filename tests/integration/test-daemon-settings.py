#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asphd --check-config says what the start says: each configuration the
start refuses (a token file that is missing,
empty, short, or readable by others; a tcp_listen that is not HOST:PORT or
does not resolve; an operator group that does not exist), --check-config
refuses with the same lines, each naming the setting and its place, and
both exit 3. tcp_listen takes host names as well as numeric addresses."""
import json
import os
import socket
import subprocess

from daemontest import ASPHD, Daemon, expect, finish, mock_instrument, free_port

TOKEN = "Kq8vT2mXw9LpZr4bNc7YhGd3"


def errors(text):
    """The configuration errors asphd printed: its lines that name a file."""
    return sorted(x for x in text.splitlines() if x.startswith("asphd: /"))


def write_token(path, text, mode=0o600):
    with open(path, "w") as f:
        f.write(text)
    os.chmod(path, mode)


d = Daemon()
try:
    port = free_port()
    token = os.path.join(d.top, "token")
    write_token(token, TOKEN + "\n")
    base = {"instruments": [mock_instrument()]}
    tcp = dict(base, tcp_listen=f"127.0.0.1:{port}", token_file=token)

    # name, settings, files to write first (path, text, mode), the setting
    # named, what the message says
    cases = [
        ("a token file that is missing", dict(tcp, token_file=token + ".none"), [],
         "token_file", "cannot read the token file"),
        ("an empty token file", tcp, [(token, "", 0o600)], "token_file", "is empty"),
        ("a token file with an empty first line", tcp, [(token, "\n" + TOKEN + "\n", 0o600)],
         "token_file", "is empty"),
        ("a short token", tcp, [(token, "short-token\n", 0o600)], "token_file",
         "shorter than 16 characters"),
        ("a token file its group can read", tcp, [(token, TOKEN, 0o640)], "token_file",
         "readable by its owner only"),
        ("a token file everyone can read", tcp, [(token, TOKEN, 0o604)], "token_file",
         "readable by its owner only"),
        ("a tcp_listen without a port", dict(tcp, tcp_listen="localhost"), [], "tcp_listen",
         "HOST:PORT"),
        ("a tcp_listen port out of range", dict(tcp, tcp_listen="localhost:70000"), [],
         "tcp_listen", "HOST:PORT"),
        ("a tcp_listen without a host", dict(tcp, tcp_listen=f":{port}"), [], "tcp_listen",
         "HOST:PORT"),
        ("a tcp_listen host that does not resolve",
         dict(tcp, tcp_listen=f"no-such-host.invalid:{port}"), [], "tcp_listen",
         "no-such-host.invalid"),
        ("an operator group that does not exist", dict(base, operator_group="no-such-group-asph"),
         [], "operator_group", "does not exist"),
        ("an mqtt section without url", dict(base, mqtt={"prefix": "lab/a"}), [], "mqtt",
         'needs "url"'),
        ("an mqtt url of another scheme", dict(base, mqtt={"url": "http://127.0.0.1:1883"}), [],
         "mqtt.url", "mqtt:// or mqtts://"),
        ("an mqtt url with a password", dict(base, mqtt={"url": "mqtt://u:p@127.0.0.1"}), [],
         "mqtt.url", "credentials_file"),
        ("an mqtt port out of range", dict(base, mqtt={"url": "mqtt://127.0.0.1:0"}), [],
         "mqtt.url", "from 1 to 65535"),
        ("an mqtt qos of 3", dict(base, mqtt={"url": "mqtt://127.0.0.1", "qos": 3}), [],
         "mqtt.qos", "0, 1 or 2"),
        ("an mqtt prefix with a wildcard", dict(base, mqtt={"url": "mqtt://h", "prefix": "a/#"}),
         [], "mqtt.prefix", "no '+' or '#'"),
        ("an unknown mqtt setting", dict(base, mqtt={"url": "mqtt://h", "user": "u"}), [],
         "mqtt.user", "unknown setting"),
        ("a ca_file for mqtt://", dict(base, mqtt={"url": "mqtt://h", "ca_file": "/etc/hostname"}),
         [], "mqtt.ca_file", "mqtts://"),
        ("a postgres password in the conninfo",
         dict(base, postgres={"conninfo": "host=db password=secret"}), [], "postgres.conninfo",
         "password_file"),
        ("a postgres section without conninfo", dict(base, postgres={}), [], "postgres",
         'needs "conninfo"'),
        ("an unknown postgres setting", dict(base, postgres={"conninfo": "host=db", "port": 5}),
         [], "postgres.port", "unknown setting"),
        ("two errors at once", dict(tcp, operator_group="no-such-group-asph"),
         [(token, "", 0o600)], "operator_group", "does not exist"),
    ]
    for name, cfg, files, key, needle in cases:
        for path, text, mode in files:
            write_token(path, text, mode)
        with open(d.config, "w") as f:
            json.dump(cfg, f, indent=1)
        chk = subprocess.run([ASPHD, "--check-config", "--config", d.config],
                             capture_output=True, text=True, timeout=60)
        said = errors(chk.stderr)
        expect(chk.returncode == 3 and said and
               any(f"{d.config}:" in x and f" {key}: " in x and needle in x for x in said),
               f"{name}: --check-config exits 3 naming {key} with its place ({chk.stderr.strip()})")
        start = subprocess.run([ASPHD, "--config", d.config, "--socket", d.socket,
                                "--state-dir", d.state], capture_output=True, text=True,
                               timeout=60)
        expect(start.returncode == 3 and errors(start.stderr) == said,
               f"{name}: the start refuses with exit 3 and the same lines "
               f"({start.returncode}: {start.stderr.strip()[-300:]})")
        expect(not os.path.exists(d.socket), f"{name}: no socket is left behind")
        write_token(token, TOKEN + "\n")
    with open(d.config, "w") as f:
        json.dump(tcp, f)
    rc = subprocess.run([ASPHD, "--check-config", "--config", d.config], capture_output=True,
                        text=True).returncode
    expect(rc == 0, "with the errors gone, --check-config says OK")

    # --- tcp_listen by host name: every address of the name is listened on
    def hello(family, address):
        with socket.socket(family, socket.SOCK_STREAM) as t:
            t.settimeout(30)
            t.connect(address)
            f = t.makefile("rw")
            f.write(json.dumps({"jsonrpc": "2.0", "id": 1, "method": "hello",
                                "params": {"token": TOKEN}}) + "\n")
            f.flush()
            return json.loads(f.readline())

    names = {"localhost": [(socket.AF_INET, ("127.0.0.1", port))]}
    v6 = socket.has_ipv6
    if v6:
        try:
            with socket.socket(socket.AF_INET6) as probe:
                probe.bind(("::1", 0))
        except OSError:
            v6 = False
    if v6:
        names["[::1]"] = [(socket.AF_INET6, ("::1", port))]
    names["127.0.0.1"] = [(socket.AF_INET, ("127.0.0.1", port))]
    for host, addresses in names.items():
        with open(d.config, "w") as f:
            json.dump(dict(tcp, tcp_listen=f"{host}:{port}"), f)
        chk = subprocess.run([ASPHD, "--check-config", "--config", d.config],
                             capture_output=True, text=True)
        expect(chk.returncode == 0, f"tcp_listen {host}:{port}: --check-config says OK "
                                    f"({chk.stderr.strip()})")
        d.start()
        for family, address in addresses:
            r = hello(family, address)
            expect(r.get("result", {}).get("peer", {}).get("operator") is True,
                   f"tcp_listen {host}:{port}: a client on {address[0]} authenticates ({r})")
        expect(d.stop() == 0, f"tcp_listen {host}:{port}: clean stop")
    if not v6:
        print("# no IPv6 loopback here: [::1] not tried")
except Exception:
    print(d.log_text())
    raise
finally:
    d.cleanup()
finish()
