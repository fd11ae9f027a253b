/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Event loop thread: the outbox and the messages of job changes. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>

#include <jansson.h>
#include <sqlite3.h>

#include "asph-proto.h"
#include "log.h"
#include "jobs-store.h"
#include "outbox.h"
#include "store.h"
#include "store-sql.h"
#include "util-hash.h"
#include "util-mem.h"
#include "util-time.h"

static const char *const sink_names[OUTBOX_N_SINKS] = { "mqtt", "postgres" };
/* Where the items a sink refused for good wait for the next start. */
static const char *const held_names[OUTBOX_N_SINKS] = { "mqtt-held", "postgres-held" };

/* Changes taken from the history per transaction. */
#define CATCH_UP_BATCH 256
/* The handed items a sink holds at most, whatever its window. */
#define WINDOW_MAX 256

struct sink_state {
	struct outbox_sink sink;
	bool set;
	int64_t handed[WINDOW_MAX];     /* ids handed, not acknowledged */
	unsigned n_handed;
	int64_t last_handed;            /* the newest id handed */
};

struct outbox {
	struct store *store;
	char daemon_id[40];
	char *host;
	char *prefix;
	int qos;
	bool postgres;
	int64_t after;                  /* the last history rowid taken */
	struct sink_state sinks[OUTBOX_N_SINKS];
};

/* ------------------------------------ the table outbox in the store */

typedef int (*store_outbox_fn)(const struct store_outbox_item *it, void *data);

static int store_outbox_add(struct store *s, struct store_outbox_item *it)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"INSERT INTO outbox (sink, topic, payload, qos, retain, message_id, created_ns)"
		" VALUES (?,?,?,?,?,?,?)");
	int r;

	if (!st)
		return -EIO;
	store_bind_text(st, 1, it->sink);
	store_bind_text(st, 2, it->topic);
	store_bind_text(st, 3, it->payload);
	sqlite3_bind_int(st, 4, it->qos);
	sqlite3_bind_int(st, 5, it->retain);
	store_bind_text(st, 6, it->message_id);
	sqlite3_bind_int64(st, 7, it->created_ns);
	r = store_step_done(st);
	if (r == 0)
		it->id = sqlite3_last_insert_rowid(store_db(s));
	return r;
}

/* Items of sink with an id above after, oldest first, at most limit. */
static int store_outbox_list(struct store *s, const char *sink, int64_t after,
			     int64_t limit, store_outbox_fn fn, void *data)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"SELECT id, sink, topic, payload, qos, retain, message_id, created_ns FROM outbox"
		" WHERE sink = ? AND id > ? ORDER BY id LIMIT ?");
	int r;

	if (!st)
		return -EIO;
	store_bind_text(st, 1, sink);
	sqlite3_bind_int64(st, 2, after);
	sqlite3_bind_int64(st, 3, limit);
	while ((r = sqlite3_step(st)) == SQLITE_ROW) {
		struct store_outbox_item it = {
			.id = sqlite3_column_int64(st, 0),
			.sink = (const char *)sqlite3_column_text(st, 1),
			.topic = (const char *)sqlite3_column_text(st, 2),
			.payload = (const char *)sqlite3_column_text(st, 3),
			.qos = sqlite3_column_int(st, 4),
			.retain = sqlite3_column_int(st, 5) != 0,
			.message_id = (const char *)sqlite3_column_text(st, 6),
			.created_ns = sqlite3_column_int64(st, 7),
		};
		int k;
		if (!it.sink || !it.payload || !it.message_id)
			return -ENOMEM;
		k = fn(&it, data);
		if (k < 0)
			return k;
	}
	return r == SQLITE_DONE ? 0 : -EIO;
}

/* Acknowledged: gone. 0 also when it was gone before. */
static int store_outbox_remove(struct store *s, int64_t id)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s, "DELETE FROM outbox WHERE id = ?");

	if (!st)
		return -EIO;
	sqlite3_bind_int64(st, 1, id);
	return store_step_done(st);
}

/* Moves item id (any sink) to sink to, keeping its id and text: 0, also
 * when it was gone. */
static int store_outbox_move(struct store *s, int64_t id, const char *to)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s, "UPDATE outbox SET sink = ? WHERE id = ?");

	if (!st)
		return -EIO;
	store_bind_text(st, 1, to);
	sqlite3_bind_int64(st, 2, id);
	return store_step_done(st);
}

/* Moves every item of sink from to sink to; *n: how many (may be NULL). */
static int store_outbox_move_all(struct store *s, const char *from, const char *to, int64_t *n)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s, "UPDATE outbox SET sink = ? WHERE sink = ?");
	int r;

	if (!st)
		return -EIO;
	store_bind_text(st, 1, to);
	store_bind_text(st, 2, from);
	r = store_step_done(st);
	if (r == 0 && n)
		*n = sqlite3_changes(store_db(s));
	return r;
}

/* Items waiting for sink. */
static int store_outbox_count(struct store *s, const char *sink, int64_t *n)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s, "SELECT COUNT(*) FROM outbox WHERE sink = ?");

	if (!st)
		return -EIO;
	store_bind_text(st, 1, sink);
	if (sqlite3_step(st) != SQLITE_ROW)
		return -EIO;
	*n = sqlite3_column_int64(st, 0);
	return 0;
}

/* ---------------------------------------------------------- the outbox */

/* A UUID (version 4) from the kernel's random numbers. */
static int make_uuid(char out[37])
{
	uint8_t b[16];

	if (getrandom(b, sizeof(b), 0) != (ssize_t)sizeof(b))
		return -EIO;
	b[6] = (uint8_t)((b[6] & 0x0f) | 0x40);
	b[8] = (uint8_t)((b[8] & 0x3f) | 0x80);
	snprintf(out, 37, "%02x%02x%02x%02x-%02x%02x-%02x%02x-%02x%02x-%02x%02x%02x%02x%02x%02x",
		 b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7], b[8], b[9], b[10], b[11], b[12],
		 b[13], b[14], b[15]);
	return 0;
}

static int load_daemon_id(struct outbox *o)
{
	_cleanup_free_ char *v = NULL;
	int r = store_meta_get(o->store, "daemon.id", &v);

	if (r == 0) {
		snprintf(o->daemon_id, sizeof(o->daemon_id), "%s", v);
		return 0;
	}
	if (r != -ENOENT)
		return r;
	r = make_uuid(o->daemon_id);
	return r < 0 ? r : store_meta_set(o->store, "daemon.id", o->daemon_id);
}

/*
 * Where the outbox stands in the history. The first start with a sink
 * begins at the newest change: the jobs before were never promised to a
 * broker or a database.
 */
static int load_cursor(struct outbox *o)
{
	_cleanup_free_ char *v = NULL;
	char buf[32];
	int r = store_meta_get(o->store, "outbox.after", &v);

	if (r == 0) {
		o->after = strtoll(v, NULL, 10);
		return 0;
	}
	if (r != -ENOENT)
		return r;
	r = store_last_change(o->store, &o->after);
	if (r < 0)
		return r;
	snprintf(buf, sizeof(buf), "%" PRId64, o->after);
	return store_meta_set(o->store, "outbox.after", buf);
}

/* A refusal may have been mended (a constraint dropped, a column widened)
 * since the last run: what was held is tried once more, in its place. */
static void release_held(struct outbox *o)
{
	for (int k = 0; k < OUTBOX_N_SINKS; k++) {
		int64_t n = 0;
		int r = store_outbox_move_all(o->store, held_names[k], sink_names[k], &n);

		if (r < 0)
			log_warning("outbox: cannot release the messages %s refused before: %s",
				    sink_names[k], strerror(-r));
		else if (n)
			log_info("outbox: %" PRId64 " message(s) that %s refused before are tried "
				 "again", n, sink_names[k]);
	}
}

int outbox_new(const struct outbox_setup *setup, struct outbox **out, struct asph_error *err)
{
	struct outbox *o = calloc(1, sizeof(*o));
	int r;

	if (!o)
		return asph_error_set(err, -ENOMEM, "out of memory");
	o->host = strdup(setup->host);
	o->prefix = setup->mqtt_prefix ? strdup(setup->mqtt_prefix) : NULL;
	o->qos = setup->mqtt_qos < 1 ? 1 : setup->mqtt_qos;
	o->postgres = setup->postgres;
	if (!o->host || (setup->mqtt_prefix && !o->prefix)) {
		outbox_free(o);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	r = store_open(setup->store_path, &o->store, err);
	if (r == 0 && (r = load_daemon_id(o)) < 0)
		asph_error_set(err, r, "cannot read or make the daemon's id: %s", strerror(-r));
	if (r == 0 && (r = load_cursor(o)) < 0)
		asph_error_set(err, r, "cannot read the outbox's place: %s", strerror(-r));
	if (r == 0)
		release_held(o);
	if (r < 0) {
		outbox_free(o);
		return r;
	}
	*out = o;
	return 0;
}

void outbox_free(struct outbox *o)
{
	if (!o)
		return;
	store_close(o->store);
	free(o->host);
	free(o->prefix);
	free(o);
}

const char *outbox_daemon_id(const struct outbox *o)
{
	return o->daemon_id;
}

void outbox_set_sink(struct outbox *o, enum outbox_sink_kind k, const struct outbox_sink *s)
{
	struct sink_state *ss = &o->sinks[k];

	*ss = (struct sink_state){ 0 };
	if (s) {
		ss->sink = *s;
		ss->set = true;
		if (!ss->sink.window || ss->sink.window > WINDOW_MAX)
			ss->sink.window = WINDOW_MAX;
	}
}

/* ------------------------------------------------------------ messages */

/* What every message says about the job. */
static json_t *job_fields(const struct outbox *o, const struct store_change *c,
			  const char *message_id)
{
	const struct job_record *j = c->job;

	return json_pack("{s:s, s:s, s:s, s:I, s:s, s:s?, s:s?, s:s?, s:s?}",
			 "message_id", message_id, "daemon", o->daemon_id, "host", o->host,
			 "job", (json_int_t)j->id, "instrument", j->instrument, "label", j->label,
			 "part", j->part, "lot", j->lot, "serial", j->serial);
}

static char *dump(json_t *m)
{
	char *s = m ? json_dumps(m, JSON_COMPACT) : NULL;

	json_decref(m);
	return s;
}

/* <prefix>/job/<id>/state: one transition. */
static char *state_message(const struct outbox *o, const struct store_change *c,
			   const char *message_id)
{
	json_t *m = job_fields(o, c, message_id);

	if (!m)
		return NULL;
	json_object_set_new(m, "state", json_string(job_state_name(c->state)));
	json_object_set_new(m, "previous", c->previous < 0 ? json_null()
			    : json_string(job_state_name((enum job_state)c->previous)));
	json_object_set_new(m, "reason", c->reason ? json_string(c->reason) : json_null());
	json_object_set_new(m, "actor", c->actor ? json_string(c->actor) : json_null());
	json_object_set_new(m, "time", proto_time_json(c->t_ns));
	return dump(m);
}

/* The hashes a result carries (its "hashes", and result.json's own). */
static json_t *result_hashes(const json_t *result, const char *result_text)
{
	json_t *files = json_deep_copy(json_object_get(result, "hashes"));
	char hex[65];

	if (!files)
		files = json_object();
	sha256_hex(result_text, strlen(result_text), hex);
	json_object_set_new(files, "result.json", json_string(hex));
	return files;
}

/* The overall verdict, or null without a tolerance. */
static json_t *verdict_of(const json_t *summary)
{
	const json_t *v = json_object_get(json_object_get(summary, "verdict"), "overall");

	return json_is_string(v) ? json_incref((json_t *)v) : json_null();
}

/* <prefix>/job/<id>/result: the summary with its verdict, and the hashes
 * of the provenance. */
static char *result_message(const struct outbox *o, const struct store_change *c,
			    const char *message_id)
{
	_cleanup_(json_decrefp) json_t *res = json_loads(c->job->result, 0, NULL);
	json_t *prov = json_object_get(res, "provenance");
	json_t *m = job_fields(o, c, message_id);

	if (!m || !res)
		return dump(m);
	json_object_set_new(m, "finished", proto_time_json(c->t_ns));
	json_object_set(m, "summary", json_object_get(res, "summary"));
	json_object_set_new(m, "verdict", verdict_of(json_object_get(res, "summary")));
	json_t *data = json_object_get(prov, "scan");

	/* a job of measured data: the data its result was made from */
	if (!data)
		data = json_object_get(prov, "measured");
	json_object_set_new(m, "provenance", json_pack("{s:O?, s:O?, s:O?, s:O?, s:o}",
		"scan", data,
		"software", json_object_get(prov, "software"),
		"plan", json_object_get(prov, "plan"),
		"submitted_by", json_object_get(prov, "submitted_by"),
		"files", result_hashes(res, c->job->result)));
	return dump(m);
}

/* The central database's row of a job that ended: everything about it. */
static char *row_message(const struct outbox *o, const struct store_change *c,
			 const char *message_id)
{
	const struct job_record *j = c->job;
	_cleanup_(json_decrefp) json_t *res = j->result && c->state == JOB_COMPLETED
		? json_loads(j->result, 0, NULL) : NULL;
	json_t *summary = json_object_get(res, "summary");
	json_t *m = job_fields(o, c, message_id);

	if (!m)
		return NULL;
	json_object_set_new(m, "state", json_string(job_state_name(c->state)));
	json_object_set_new(m, "reason", c->reason ? json_string(c->reason)
			    : j->reason && c->state != JOB_COMPLETED ? json_string(j->reason)
			    : json_null());
	json_object_set_new(m, "submitted_by", json_pack("{s:I, s:s?}", "uid", (json_int_t)j->uid,
							 "name", j->user));
	json_object_set_new(m, "submitted", proto_time_json(j->submitted_ns));
	json_object_set_new(m, "started", proto_time_json(j->started_ns));
	json_object_set_new(m, "finished", proto_time_json(c->t_ns));
	json_object_set_new(m, "points", json_integer(j->points_done));
	json_object_set_new(m, "attempts", json_integer(j->attempts));
	json_object_set(m, "summary", summary ? summary : json_null());
	json_object_set_new(m, "verdict", verdict_of(summary));
	json_object_set_new(m, "uncertainty", summary ? json_pack("{s:O?, s:O?, s:O?}",
		"standard", json_object_get(summary, "uncertainty"),
		"expanded_k2", json_object_get(summary, "uncertainty_k2"),
		"method", json_object_get(summary, "uncertainty_method")) : json_null());
	json_object_set(m, "provenance", res && json_object_get(res, "provenance")
			? json_object_get(res, "provenance") : json_null());
	json_object_set_new(m, "files", res ? result_hashes(res, j->result) : json_object());
	return dump(m);
}

struct catch_up {
	struct outbox *o;
	int r;
};

static int add_item(struct outbox *o, enum outbox_sink_kind k, const char *topic,
		    char *payload, int qos, const char *message_id)
{
	struct store_outbox_item it = {
		.sink = sink_names[k], .topic = topic, .payload = payload, .qos = qos,
		.message_id = message_id, .created_ns = now_realtime_ns(),
	};
	int r = payload ? store_outbox_add(o->store, &it) : -ENOMEM;

	free(payload);
	return r;
}

/* The messages of one change. */
static int take_change(const struct store_change *c, void *data)
{
	struct catch_up *cu = data;
	struct outbox *o = cu->o;
	char topic[512], id[96];
	int r = 0;

	if (o->prefix) {
		snprintf(id, sizeof(id), "%s:%" PRId64 ":state", o->daemon_id, c->rowid);
		snprintf(topic, sizeof(topic), "%s/job/%" PRId64 "/state", o->prefix, c->job->id);
		r = add_item(o, OUTBOX_MQTT, topic, state_message(o, c, id), o->qos, id);
		if (r == 0 && c->state == JOB_COMPLETED && c->job->result) {
			snprintf(id, sizeof(id), "%s:%" PRId64 ":result", o->daemon_id, c->rowid);
			snprintf(topic, sizeof(topic), "%s/job/%" PRId64 "/result", o->prefix,
				 c->job->id);
			r = add_item(o, OUTBOX_MQTT, topic, result_message(o, c, id), o->qos, id);
		}
	}
	if (r == 0 && o->postgres && job_state_final(c->state)) {
		snprintf(id, sizeof(id), "%s:%" PRId64 ":row", o->daemon_id, c->rowid);
		r = add_item(o, OUTBOX_POSTGRES, NULL, row_message(o, c, id), 1, id);
	}
	if (r == 0)
		o->after = c->rowid;
	return r;
}

/* One batch of changes in one transaction: > 0 when there may be more. */
static int catch_up_batch(struct outbox *o)
{
	struct catch_up cu = { .o = o };
	int64_t before = o->after;
	char buf[32];
	int r = store_begin(o->store);

	if (r < 0)
		return r;
	r = store_changes(o->store, o->after, CATCH_UP_BATCH, take_change, &cu);
	if (r == 0 && o->after != before) {
		snprintf(buf, sizeof(buf), "%" PRId64, o->after);
		r = store_meta_set(o->store, "outbox.after", buf);
	}
	if (r == 0)
		r = store_commit(o->store);
	if (r < 0) {
		store_rollback(o->store);
		o->after = before;
		return r;
	}
	return o->after - before >= CATCH_UP_BATCH ? 1 : 0;
}

int outbox_catch_up(struct outbox *o)
{
	int r;

	if (!o->prefix && !o->postgres)
		return 0;
	while ((r = catch_up_batch(o)) > 0)
		;
	if (r < 0) {
		log_error("outbox: cannot record the messages of the job changes: %s; they are "
			  "taken at the next change", strerror(-r));
		return r;
	}
	for (int k = 0; k < OUTBOX_N_SINKS; k++)
		outbox_pump(o, (enum outbox_sink_kind)k);
	return 0;
}

/* ------------------------------------------------------------ sinks */

struct pump {
	struct sink_state *ss;
	unsigned room;
};

static int hand(const struct store_outbox_item *it, void *data)
{
	struct pump *p = data;
	struct sink_state *ss = p->ss;

	if (!p->room || ss->sink.send(ss->sink.data, it) < 0)
		return -EAGAIN;
	ss->handed[ss->n_handed++] = it->id;
	ss->last_handed = it->id;
	p->room--;
	return 0;
}

void outbox_pump(struct outbox *o, enum outbox_sink_kind k)
{
	struct sink_state *ss = &o->sinks[k];
	struct pump p = { .ss = ss };
	int r;

	if (!ss->set || ss->n_handed >= ss->sink.window)
		return;
	p.room = ss->sink.window - ss->n_handed;
	r = store_outbox_list(o->store, sink_names[k], ss->last_handed, p.room, hand, &p);
	if (r < 0 && r != -EAGAIN)
		log_error("outbox: cannot read the messages for %s: %s", sink_names[k],
			  strerror(-r));
}

/* Item id is no longer the sink's to acknowledge. */
static void forget_handed(struct sink_state *ss, int64_t id)
{
	for (unsigned i = 0; i < ss->n_handed; i++)
		if (ss->handed[i] == id) {
			ss->handed[i] = ss->handed[--ss->n_handed];
			return;
		}
}

void outbox_done(struct outbox *o, enum outbox_sink_kind k, int64_t id)
{
	struct sink_state *ss = &o->sinks[k];
	int r;

	forget_handed(ss, id);
	r = store_outbox_remove(o->store, id);
	if (r < 0)
		log_warning("outbox: cannot delete message %" PRId64 " (%s): it will be sent "
			    "again after a restart", id, strerror(-r));
	outbox_pump(o, k);
}

void outbox_hold(struct outbox *o, enum outbox_sink_kind k, int64_t id, const char *why)
{
	struct sink_state *ss = &o->sinks[k];
	int r;

	forget_handed(ss, id);
	r = store_outbox_move(o->store, id, held_names[k]);
	if (r < 0)
		log_error("%s: message %" PRId64 " refused (%s), and it cannot be set aside (%s): "
			  "it is sent again after a restart", sink_names[k], id, why, strerror(-r));
	else
		log_error("%s: message %" PRId64 " refused for good: %s; it is kept in the outbox "
			  "(%s) and tried again at the next start", sink_names[k], id, why,
			  held_names[k]);
	outbox_pump(o, k);
}

int64_t outbox_held(struct outbox *o, enum outbox_sink_kind k)
{
	int64_t n = 0;

	return store_outbox_count(o->store, held_names[k], &n) < 0 ? -1 : n;
}

void outbox_reset(struct outbox *o, enum outbox_sink_kind k)
{
	struct sink_state *ss = &o->sinks[k];

	ss->n_handed = 0;
	ss->last_handed = 0;
}

const char *outbox_sink_name(enum outbox_sink_kind k)
{
	return (unsigned)k < OUTBOX_N_SINKS ? sink_names[k] : "unknown";
}

static int take_created(const struct store_outbox_item *it, void *data)
{
	*(int64_t *)data = it->created_ns;
	return 0;
}

int64_t outbox_oldest_ns(struct outbox *o, enum outbox_sink_kind k)
{
	int64_t ns = 0;

	return store_outbox_list(o->store, sink_names[k], 0, 1, take_created, &ns) < 0 ? -1 : ns;
}

int64_t outbox_waiting(struct outbox *o, enum outbox_sink_kind k)
{
	int64_t n = 0;

	return store_outbox_count(o->store, sink_names[k], &n) < 0 ? -1 : n;
}
