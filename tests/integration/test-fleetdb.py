#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The central results store against a real PostgreSQL server made here
(initdb and pg_ctl as an unprivileged user, a unix socket in a temporary
directory; one server for the whole file): the schema made from empty by
asphd --db-migrate (and three migrations at once), three daemons writing
at the same time, the database down during a job and back (no row lost or
duplicated), a daemon killed with unsent rows, the documented view and
asphctl fleet list."""
import json
import os
import sqlite3
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))
from daemontest import ASPHCTL, ASPHD, Client, Daemon, expect, finish, mock_instrument  # noqa: E402
from fleettest import Postgres  # noqa: E402


def wait(cond, timeout, what):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if cond():
            return True
        time.sleep(0.1)
    raise TimeoutError(what)


def migrate(config):
    return subprocess.run([ASPHD, "--db-migrate", "--config", config], capture_output=True,
                          text=True, timeout=300)


def rows(pg, where="true"):
    return pg.psql("SELECT daemon_id, job_id, state, part, lot, serial, verdict, rms_nm, "
                   f"message_id, files->>'result.json' FROM asphd.results WHERE {where} "
                   "ORDER BY daemon_id, job_id")


def outbox(d, sink="postgres"):
    """The daemon's outbox rows for the database (or those it refused)."""
    db = sqlite3.connect(os.path.join(d.state, "jobs.sqlite"))
    try:
        return db.execute("SELECT id, sink, topic, payload, qos, retain, message_id, created_ns "
                          "FROM outbox WHERE sink = ? ORDER BY id", (sink,)).fetchall()
    finally:
        db.close()


def daemon_id(d):
    db = sqlite3.connect(os.path.join(d.state, "jobs.sqlite"))
    try:
        return db.execute("SELECT value FROM meta WHERE key = 'daemon.id'").fetchone()[0]
    finally:
        db.close()


def submit(c, n, **extra):
    return [c.call("job.submit", dict({"lens": "strong", "plan": {"method": "fermat", "points": 200}},
                                      **extra))["id"] for _ in range(n)]


pg = Postgres()
daemons = []
try:
    cfg = {"postgres": {"conninfo": pg.conninfo}}

    # --- the schema, from empty; three migrations at once
    first = Daemon(instruments=[mock_instrument(time_factor=0.005)], extra=cfg)
    daemons.append(first)
    m = migrate(first.config)
    expect(m.returncode == 0 and "from version 0 to 1" in m.stdout,
           f"--db-migrate makes the schema from empty ({m.stdout.strip()} {m.stderr.strip()})")
    pg.psql("DROP SCHEMA asphd CASCADE")
    ps = [subprocess.Popen([ASPHD, "--db-migrate", "--config", first.config],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
          for _ in range(3)]
    outs = [p.communicate(timeout=300) for p in ps]
    expect(all(p.returncode == 0 for p in ps) and
           sum("from version 0 to 1" in o for o, _ in outs) == 1,
           f"three migrations at once: one makes the schema, two find it made ({outs})")
    expect(pg.psql("SELECT version FROM asphd.schema_version") == [["1"]],
           "the schema's version is recorded once")
    m = migrate(first.config)
    expect(m.returncode == 0 and "at version 1 already" in m.stdout, "a second run changes nothing")
    bad = Daemon(extra={"postgres": {"conninfo": pg.conninfo.replace(f"port={pg.port}", "port=1")}})
    m = migrate(bad.config)
    expect(m.returncode == 1 and "cannot connect" in m.stderr,
           f"no server: --db-migrate says so, exit 1 ({m.stderr.strip()[:200]})")
    bad.cleanup()

    # --- three daemons writing at the same time
    for _ in range(2):
        daemons.append(Daemon(instruments=[mock_instrument(time_factor=0.005)], extra=cfg))
    for d in daemons:
        d.start()
    clients = [Client(d.socket) for d in daemons]
    jobs = []
    for i, c in enumerate(clients):
        jobs.append(submit(c, 3, part="AS-2041", lot=f"L-{i}", serial="0042"))
    ids = [daemon_id(d) for d in daemons]
    expect(len(set(ids)) == 3, f"each daemon has its own id ({ids})")
    wait(lambda: len(rows(pg)) == 9, 300, "nine rows")
    got = rows(pg)
    expect(len(got) == 9 and {(r[0], int(r[1])) for r in got} ==
           {(ids[i], j) for i in range(3) for j in jobs[i]},
           "three daemons at once: one row per (daemon id, job id), nine in all")
    r0 = clients[0].call("job.result", {"id": jobs[0][0]})
    row = [r for r in got if r[0] == ids[0] and int(r[1]) == jobs[0][0]][0]
    expect(row[2] == "completed" and row[3:6] == ["AS-2041", "L-0", "0042"] and row[6] is None and
           abs(float(row[7]) - r0["summary"]["rms_nm"]) < 1e-9 * max(1, abs(r0["summary"]["rms_nm"])),
           f"a row holds the state, part/lot/serial, verdict (none without a tolerance) and the "
           f"summary's RMS ({row[:8]})")
    prov = pg.psql(f"SELECT provenance->'scan'->>'sha256', scan_sha256, summary->>'n_points', "
                   f"uncertainty IS NOT NULL, files ? 'residuals.csv' FROM asphd.results "
                   f"WHERE daemon_id = '{ids[0]}' AND job_id = {jobs[0][0]}")[0]
    expect(prov[0] == prov[1] == r0["provenance"]["scan"]["sha256"] and
           int(prov[2]) == r0["summary"]["n_points"] and prov[3] == "t" and prov[4] == "t",
           "and the provenance, the scan's hash, the summary, the uncertainty and the files' hashes")

    # --- a job with a tolerance: its verdict in the row
    tol_job = clients[0].call("job.submit", {"lens": "strong", "plan": {"method": "fermat",
                                                                       "points": 200},
                                             "tolerance": {"rms_nm": {"t": 1}}})["id"]
    wait(lambda: rows(pg, f"daemon_id = '{ids[0]}' AND job_id = {tol_job}"), 120,
         "the row of the job with a tolerance")
    verdict = clients[0].call("job.get", {"id": tol_job})["verdict"]
    row = rows(pg, f"daemon_id = '{ids[0]}' AND job_id = {tol_job}")[0]
    expect(verdict in ("pass", "fail", "undecided") and row[6] == verdict,
           f"a job with a tolerance: the row's verdict is the job's ({row[6]}, {verdict})")

    # --- the database down during a job, then back
    c = clients[1]
    c.call("events.subscribe", {"events": ["job"]})
    before = len(rows(pg))
    pg.stop("immediate")
    down = submit(c, 2, serial="0099")
    c.call("job.cancel", {"id": down[1]})
    c.wait_state(down[0], ["completed"])
    expect(c.call("daemon.status")["status"] in ("idle",), "the daemon measures on without its database")
    wait(lambda: len(outbox(daemons[1])) == 2, 30, "the two rows in the outbox")
    waiting = outbox(daemons[1])
    pg.start()
    wait(lambda: len(rows(pg)) == before + 2, 300, "the rows after the database came back")
    after = rows(pg, f"daemon_id = '{ids[1]}' AND job_id IN ({down[0]}, {down[1]})")
    expect(len(after) == 2 and {r[2] for r in after} == {"completed", "cancelled"},
           f"database down and back: both jobs' rows arrive, once ({[r[2] for r in after]})")
    time.sleep(2)
    expect(len(rows(pg)) == before + 2, "no row duplicated or lost")

    # --- a daemon killed with unsent rows, then started again
    d = daemons[2]
    c2 = clients[2]
    c2.call("events.subscribe", {"events": ["job"]})
    pg.stop("immediate")
    killed = submit(c2, 1, serial="0100")
    c2.wait_state(killed[0], ["completed"])
    time.sleep(0.5)
    c2.close()
    d.kill()
    pg.start()
    d.start()
    clients[2] = Client(d.socket)
    wait(lambda: rows(pg, f"daemon_id = '{ids[2]}' AND job_id = {killed[0]}"), 300,
         "the row of the killed daemon")
    expect(len(rows(pg, f"daemon_id = '{ids[2]}' AND job_id = {killed[0]}")) == 1,
           "a daemon killed with an unsent row sends it after its restart")

    # --- a job run again replaces its row; the same message twice changes nothing
    stamp = pg.psql(f"SELECT updated_at FROM asphd.results WHERE daemon_id = '{ids[0]}' "
                    f"AND job_id = {jobs[0][0]}")
    clients[0].call("events.subscribe", {"events": ["job"]})
    clients[0].call("job.requeue", {"id": jobs[0][0], "restart": True})
    clients[0].wait_state(jobs[0][0], ["running", "completed"])
    clients[0].wait_state(jobs[0][0], ["completed"])
    wait(lambda: pg.psql(f"SELECT attempts FROM asphd.results WHERE daemon_id = '{ids[0]}' AND "
                         f"job_id = {jobs[0][0]}") == [["2"]], 120, "the row of the second run")
    expect(pg.psql(f"SELECT count(*) FROM asphd.results WHERE daemon_id = '{ids[0]}' AND job_id = "
                   f"{jobs[0][0]}") == [["1"]] and pg.psql(
                       f"SELECT updated_at FROM asphd.results WHERE daemon_id = '{ids[0]}' AND "
                       f"job_id = {jobs[0][0]}") != stamp,
           "a job re-queued and ended again replaces its row")
    mid = pg.psql(f"SELECT message_id FROM asphd.results WHERE daemon_id = '{ids[0]}' AND "
                  f"job_id = {jobs[0][0]}")[0][0]
    expect(mid.startswith(ids[0] + ":"), f"the row keeps its message id ({mid})")

    # the rows of the outage delivered a second time (as after a crash
    # between the commit and the outbox's delete): nothing changes
    where = f"daemon_id = '{ids[1]}' AND job_id IN ({down[0]}, {down[1]})"
    stamps = pg.psql(f"SELECT job_id, updated_at, message_id FROM asphd.results WHERE {where} "
                     "ORDER BY job_id")
    clients[1].close()
    expect(daemons[1].stop() == 0, "clean stop")
    db = sqlite3.connect(os.path.join(daemons[1].state, "jobs.sqlite"))
    db.executemany("INSERT INTO outbox (sink, topic, payload, qos, retain, message_id, created_ns)"
                   " VALUES (?, ?, ?, ?, ?, ?, ?)", [w[1:] for w in waiting])
    db.commit()
    db.close()
    daemons[1].start()
    clients[1] = Client(daemons[1].socket)
    wait(lambda: not outbox(daemons[1]), 60, "the rows delivered again")
    expect(pg.psql(f"SELECT job_id, updated_at, message_id FROM asphd.results WHERE {where} "
                   "ORDER BY job_id") == stamps and len(stamps) == 2,
           "the same rows delivered twice: acknowledged, and the rows are as they were")

    # --- a row the database refuses for what it holds (a constraint an
    # administrator added): set aside in the outbox, the rows behind it go
    # on, and the next start tries it again
    pg.psql("ALTER TABLE asphd.results ADD CONSTRAINT no_scrap CHECK (part IS DISTINCT FROM "
            "'SCRAP')")
    c = clients[1]
    c.call("events.subscribe", {"events": ["job"]})
    scrap = submit(c, 1, part="SCRAP", serial="0101")[0]
    c.wait_state(scrap, ["completed"])
    behind = submit(c, 1, part="AS-2041", serial="0102")[0]
    wait(lambda: rows(pg, f"daemon_id = '{ids[1]}' AND job_id = {behind}"), 120,
         "the row behind the refused one")
    # the row behind is in the database before its acknowledgement has
    # emptied the outbox
    wait(lambda: outbox(daemons[1], "postgres-held") and not outbox(daemons[1]), 30,
         "the refused row set aside, the row behind it acknowledged")
    held = outbox(daemons[1], "postgres-held")
    log = daemons[1].log_text()
    expect(len(held) == 1 and json.loads(held[0][3]).get("job") == scrap and
           not outbox(daemons[1]) and not rows(pg, f"daemon_id = '{ids[1]}' AND job_id = {scrap}"),
           f"a refused row is kept aside in the outbox, and the row behind it arrives "
           f"({[json.loads(h[3]).get('job') for h in held]})")
    expect("refused for good" in log and "no_scrap" in log,
           "the log says which row was refused and the server's reason")
    h = c.call("daemon.health")
    expect(h["status"] == "degraded" and any(
        r["check"] == "outbox_held" and r["detail"].startswith("postgres: 1 message(s) refused")
        for r in h["reasons"]), f"the health is degraded by the refused row: outbox_held ({h})")
    pg.psql("ALTER TABLE asphd.results DROP CONSTRAINT no_scrap")
    c.close()
    expect(daemons[1].stop() == 0, "clean stop")
    daemons[1].start()
    clients[1] = Client(daemons[1].socket)
    wait(lambda: rows(pg, f"daemon_id = '{ids[1]}' AND job_id = {scrap}"), 120,
         "the refused row, once the constraint is gone and the daemon started again")
    # (the daemon deletes its copy once the server has acknowledged the row,
    # a moment after the row is there to see)
    try:
        wait(lambda: not outbox(daemons[1], "postgres-held") and not outbox(daemons[1]), 60,
             "the outbox emptied")
    except TimeoutError:
        pass
    expect(not outbox(daemons[1], "postgres-held") and not outbox(daemons[1]),
           "after the restart the refused row is delivered and the outbox is empty")

    # --- the view and asphctl fleet list
    view = pg.psql("SELECT host, job_id, verdict, part FROM asphd.fleet_results LIMIT 3")
    expect(len(view) == 3, f"the view asphd.fleet_results lists the newest first ({view[:1]})")
    p = subprocess.run([ASPHCTL, "--json", "fleet", "list", "--db", pg.conninfo, "--serial", "0099"],
                       capture_output=True, text=True, timeout=60)
    listed = json.loads(p.stdout)["results"] if p.returncode == 0 else []
    expect(len(listed) == 2 and {r["state"] for r in listed} == {"completed", "cancelled"} and
           all(r["daemon"] == ids[1] for r in listed),
           f"asphctl fleet list --serial 0099 --json: the two rows ({p.stderr.strip()})")
    p = subprocess.run([ASPHCTL, "fleet", "list", "--db", pg.conninfo, "--limit", "5"],
                       capture_output=True, text=True, timeout=60)
    expect(p.returncode == 0 and "(5 result(s))" in p.stdout and "AS-2041" in p.stdout,
           f"asphctl fleet list: a table of the newest ({p.stdout.splitlines()[:2]})")
    p = subprocess.run([ASPHCTL, "fleet", "list", "--db", pg.conninfo.replace(f"port={pg.port}",
                                                                                "port=1")],
                       capture_output=True, text=True, timeout=60)
    expect(p.returncode == 7 and "cannot connect" in p.stderr, "no database: exit 7, said why")
    p = subprocess.run([ASPHCTL, "fleet", "list", "--db", pg.conninfo, "--verdict", "maybe"],
                       capture_output=True, text=True, timeout=60)
    expect(p.returncode == 2 and "not pass, fail or undecided" in p.stderr,
           f"an unknown verdict: a usage error ({p.stderr.strip()})")
    for c in clients:
        c.close()
    for d in daemons:
        expect(d.stop() == 0, "clean stop")
except Exception:
    for d in daemons:
        print(d.log_text()[-2000:])
    raise
finally:
    for d in daemons:
        d.cleanup()
    pg.cleanup()
finish()
