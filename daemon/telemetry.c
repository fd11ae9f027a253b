/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Event loop thread: the retained status, instrument states, progress. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph-proto.h"
#include "config.h"
#include "log.h"
#include "telemetry.h"
#include "util-mem.h"
#include "util-time.h"

/* The last progress message of a running job. */
struct progress_mark {
	int64_t job;
	int64_t at_ns;
};

struct telemetry {
	char *prefix, *daemon_id, *host;
	char *status_topic;
	int qos;
	int64_t started_ns;
	const struct jobs *jobs;
	const struct instruments *instruments;
	struct mqtt *mqtt;
	char *status;                   /* the status as last published */
	char **instrument_state;        /* per instrument, as last published */
	struct progress_mark *marks;    /* per instrument */
	uint64_t progress_dropped;
};

int telemetry_new(const struct telemetry_setup *setup, struct telemetry **out)
{
	size_t n = instruments_count(setup->instruments);
	struct telemetry *t = calloc(1, sizeof(*t));

	if (!t)
		return -ENOMEM;
	t->prefix = strdup(setup->prefix);
	t->daemon_id = strdup(setup->daemon_id);
	t->host = strdup(setup->host);
	t->qos = setup->qos;
	t->started_ns = setup->started_ns;
	t->jobs = setup->jobs;
	t->instruments = setup->instruments;
	t->instrument_state = calloc(n ? n : 1, sizeof(*t->instrument_state));
	t->marks = calloc(n ? n : 1, sizeof(*t->marks));
	if (!t->prefix || !t->daemon_id || !t->host || !t->instrument_state || !t->marks ||
	    asprintf(&t->status_topic, "%s/status", setup->prefix) < 0) {
		t->status_topic = NULL;
		telemetry_free(t);
		return -ENOMEM;
	}
	*out = t;
	return 0;
}

void telemetry_free(struct telemetry *t)
{
	if (!t)
		return;
	for (size_t i = 0; t->instrument_state && i < instruments_count(t->instruments); i++)
		free(t->instrument_state[i]);
	free(t->instrument_state);
	free(t->marks);
	free(t->status);
	free(t->status_topic);
	free(t->prefix);
	free(t->daemon_id);
	free(t->host);
	free(t);
}

void telemetry_set_mqtt(struct telemetry *t, struct mqtt *m)
{
	t->mqtt = m;
}

const char *telemetry_status_topic(const struct telemetry *t)
{
	return t->status_topic;
}

static json_t *status_base(const struct telemetry *t, const char *state)
{
	return json_pack("{s:s, s:s, s:s, s:s, s:o}", "state", state, "daemon", t->daemon_id,
			 "host", t->host, "version", ASPH_VERSION, "since",
			 proto_time_json(t->started_ns));
}

char *telemetry_offline(const struct telemetry *t)
{
	json_t *m = status_base(t, "offline");
	char *s = m ? json_dumps(m, JSON_COMPACT) : NULL;

	json_decref(m);
	return s;
}

/* One instrument as the retained topics show it (no progress: it would
 * make the retained message change all the time). */
static json_t *instrument_json(const struct telemetry *t, size_t i)
{
	const struct instrument_activity *a = jobs_activity(t->jobs, i);

	return json_pack("{s:s, s:s, s:o, s:o, s:o}",
			 "instrument", instruments_get(t->instruments, i)->name,
			 "state", instrument_state_name(a),
			 "job", a->job ? json_integer(a->job) : json_null(),
			 "fault", a->fault ? json_string(a->fault) : json_null(),
			 "lock", instrument_lock_to_json(a->lock));
}

static char *status_text(const struct telemetry *t)
{
	json_t *m = status_base(t, "online"), *list = json_array();
	char *s;

	for (size_t i = 0; list && i < instruments_count(t->instruments); i++)
		json_array_append_new(list, instrument_json(t, i));
	json_object_set_new(m, "instruments", list);
	json_object_set_new(m, "queue", json_pack("{s:b}", "running",
						  jobs_queue_running(t->jobs)));
	s = m ? json_dumps(m, JSON_COMPACT) : NULL;
	json_decref(m);
	return s;
}

/* Publishes text on topic, retained, unless it is what was published
 * last (*last), or force. */
static void publish_retained(struct telemetry *t, const char *topic, char *text, char **last,
			     bool force)
{
	if (!text)
		return;
	if (!force && *last && !strcmp(*last, text)) {
		free(text);
		return;
	}
	if (mqtt_publish(t->mqtt, topic, text, t->qos, true, 0) < 0) {
		/* Down: published whole when the link is back. */
		free(text);
		return;
	}
	free(*last);
	*last = text;
}

static void publish_states(struct telemetry *t, bool force)
{
	char topic[512];

	if (!t->mqtt || !mqtt_up(t->mqtt))
		return;
	publish_retained(t, t->status_topic, status_text(t), &t->status, force);
	for (size_t i = 0; i < instruments_count(t->instruments); i++) {
		json_t *m = instrument_json(t, i);
		snprintf(topic, sizeof(topic), "%s/instrument/%s/state", t->prefix,
			 instruments_get(t->instruments, i)->name);
		publish_retained(t, topic, m ? json_dumps(m, JSON_COMPACT) : NULL,
				 &t->instrument_state[i], force);
		json_decref(m);
	}
}

void telemetry_link_up(struct telemetry *t)
{
	publish_states(t, true);
}

/* <prefix>/job/<id>/progress: at most every 500 ms per job, and only
 * while the broker keeps up. */
static void publish_progress(struct telemetry *t, const struct event *ev)
{
	const char *instrument = json_string_value(json_object_get(ev->params, "instrument"));
	int i = instrument ? instruments_find(t->instruments, instrument) : -1;
	int64_t now = now_realtime_ns();
	_cleanup_free_ char *text = NULL;
	struct progress_mark *mark;
	char topic[512];
	json_t *m;

	if (i < 0)
		return;
	mark = &t->marks[i];
	if (mark->job == ev->job && now - mark->at_ns < TELEMETRY_PROGRESS_INTERVAL_NS)
		return;
	if (!t->mqtt || !mqtt_up(t->mqtt) || mqtt_pending(t->mqtt) > TELEMETRY_PROGRESS_BACKLOG) {
		t->progress_dropped++;
		return;
	}
	m = json_deep_copy(ev->params);
	if (!m)
		return;
	json_object_set_new(m, "time", proto_time_json(now));
	text = json_dumps(m, JSON_COMPACT);
	json_decref(m);
	snprintf(topic, sizeof(topic), "%s/job/%" PRId64 "/progress", t->prefix, ev->job);
	if (text && mqtt_publish(t->mqtt, topic, text, 0, false, 0) == 0)
		*mark = (struct progress_mark){ .job = ev->job, .at_ns = now };
	else
		t->progress_dropped++;
}

void telemetry_watch(const struct event *ev, void *data)
{
	struct telemetry *t = data;

	if (ev->class == EVENT_PROGRESS)
		publish_progress(t, ev);
	else
		publish_states(t, false);
}
