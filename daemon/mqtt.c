/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The event loop's side and libmosquitto's thread (mqtt_thread()). */
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <jansson.h>
#include <mosquitto.h>

#include "asph/error.h"
#include "log.h"
#include "mailbox.h"
#include "mqtt.h"
#include "util-mem.h"
#include "util-time.h"

/* The delays between tries to connect: 1 s, doubling up to this. */
#define RECONNECT_MAX_S 30
#define KEEPALIVE_S 30
/* How long mqtt_free() waits for the goodbye, and for the thread. */
#define GOODBYE_WAIT_NS (2 * NS_PER_SEC)
#define JOIN_WAIT_S 5

/* ------------------------------------------------------ credentials */

void mqtt_credentials_clear(struct mqtt_credentials *c)
{
	if (c->password)
		explicit_bzero(c->password, strlen(c->password));
	free(c->username);
	free(c->password);
	free(c->certfile);
	free(c->keyfile);
	memset(c, 0, sizeof(*c));
}

struct checker {
	const struct settings *s;
	settings_error_fn report;
	void *data;
	int n;
};

static void complain(struct checker *ck, const char *field, int code, const char *fmt, ...)
	__attribute__((format(printf, 4, 5)));

static void complain(struct checker *ck, const char *field, int code, const char *fmt, ...)
{
	va_list ap;

	va_start(ap, fmt);
	settings_vreport(ck->s, field, code, ck->report, ck->data, fmt, ap);
	va_end(ap);
	ck->n++;
}

static void check_readable(struct checker *ck, const char *field, const char *what,
			   const char *path)
{
	if (path && access(path, R_OK) < 0)
		complain(ck, field, -errno, "cannot read the %s %s: %s", what, path, strerror(errno));
}

static char *member(json_t *o, const char *name, struct checker *ck, const char *path)
{
	json_t *v = json_object_get(o, name);

	if (!v)
		return NULL;
	if (!json_is_string(v) || !json_string_length(v)) {
		complain(ck, "mqtt.credentials_file", -EINVAL, "%s: \"%s\" must be a non-empty "
			 "string", path, name);
		return NULL;
	}
	return strdup(json_string_value(v));
}

static void read_credentials(struct checker *ck, const char *path, struct mqtt_credentials *c)
{
	static const char *const known[] = { "username", "password", "certfile", "keyfile" };
	_cleanup_(json_decrefp) json_t *root = NULL;
	_cleanup_close_ int fd = open(path, O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
	struct stat st;
	json_error_t je;
	const char *key;
	json_t *v;

	if (fd < 0) {
		complain(ck, "mqtt.credentials_file", -errno, "cannot read the credentials file "
			 "%s: %s", path, strerror(errno));
		return;
	}
	if (fstat(fd, &st) < 0 || (st.st_mode & 0077) || st.st_uid != geteuid()) {
		complain(ck, "mqtt.credentials_file", -EPERM, "the credentials file %s must belong "
			 "to the daemon's user (uid %u) and be readable by its owner only", path,
			 (unsigned)geteuid());
		return;
	}
	root = json_loadfd(fd, JSON_REJECT_DUPLICATES, &je);
	if (!json_is_object(root)) {
		/* jansson's line and column: -1 when it has none (a document
		 * that is not an object); asph_error_format() leaves them out */
		struct asph_error e;
		char where[512];

		asph_error_clear(&e);
		asph_error_set_at(&e, -EINVAL, path, root ? 0 : je.line, root ? 0 : je.column, NULL,
				  "%s", root ? "must be a JSON object" : je.text);
		complain(ck, "mqtt.credentials_file", -EINVAL, "%s",
			 asph_error_format(&e, where, sizeof(where)));
		return;
	}
	json_object_foreach(root, key, v) {
		bool ok = false;
		for (size_t i = 0; i < ARRAY_SIZE(known); i++)
			ok |= !strcmp(key, known[i]);
		if (!ok)
			complain(ck, "mqtt.credentials_file", -EINVAL, "%s: unknown member \"%.64s\" "
				 "(username, password, certfile, keyfile)", path, key);
	}
	c->username = member(root, "username", ck, path);
	c->password = member(root, "password", ck, path);
	c->certfile = member(root, "certfile", ck, path);
	c->keyfile = member(root, "keyfile", ck, path);
	if (c->password && !c->username)
		complain(ck, "mqtt.credentials_file", -EINVAL, "%s: a password needs a username",
			 path);
	if (!c->certfile != !c->keyfile)
		complain(ck, "mqtt.credentials_file", -EINVAL, "%s: a client certificate needs "
			 "both certfile and keyfile", path);
	if ((c->certfile || c->keyfile) && !ck->s->mqtt->tls)
		complain(ck, "mqtt.credentials_file", -EINVAL, "%s: a client certificate is for an "
			 "mqtts:// broker", path);
	check_readable(ck, "mqtt.credentials_file", "client certificate", c->certfile);
	check_readable(ck, "mqtt.credentials_file", "client key", c->keyfile);
}

int mqtt_credentials_load(const struct settings *s, struct mqtt_credentials *out,
			  settings_error_fn report, void *data)
{
	struct checker ck = { .s = s, .report = report, .data = data };

	memset(out, 0, sizeof(*out));
	if (!s->mqtt)
		return 0;
	if (s->mqtt->credentials_file)
		read_credentials(&ck, s->mqtt->credentials_file, out);
	check_readable(&ck, "mqtt.ca_file", "CA file", s->mqtt->ca_file);
	if (ck.n) {
		mqtt_credentials_clear(out);
		return -EINVAL;
	}
	return 0;
}

/* ------------------------------------------------------ the link */

enum note_kind { NOTE_ACK, NOTE_UP, NOTE_DOWN };

/* What libmosquitto's thread tells the loop. */
struct note {
	enum note_kind kind;
	int mid;
	char why[128];
};

/* A publication waiting for the broker. */
struct inflight {
	int mid;
	int64_t tag;
	int qos;
};

struct mqtt {
	struct mailbox *mailbox;        /* notes for the loop */
	struct mosquitto *mosq;
	char *host;
	int port;
	char *will_topic;
	bool told_down;                 /* link() knows the link is down */
	void (*acked)(void *data, int64_t tag);
	void (*link)(void *data, bool up, const char *why);
	void *data;
	bool up;                        /* as the loop knows it */
	struct inflight *inflight;      /* the loop's */
	size_t n_inflight, cap_inflight;

	pthread_t thread;
	bool thread_started;
	pthread_mutex_t lock;           /* what follows */
	pthread_cond_t cond;
	bool stopping;
	int goodbye_mid;                /* > 0: mqtt_free() waits for it */
	bool goodbye_done;
};

/* On libmosquitto's thread: a note for the loop. */
static void post(struct mqtt *m, enum note_kind kind, int mid, const char *why)
{
	struct note n = { .kind = kind, .mid = mid };

	pthread_mutex_lock(&m->lock);
	if (kind == NOTE_ACK && mid == m->goodbye_mid && mid > 0) {
		m->goodbye_done = true;
		pthread_cond_broadcast(&m->cond);
	}
	pthread_mutex_unlock(&m->lock);
	snprintf(n.why, sizeof(n.why), "%s", why ? why : "");
	/* Lost when memory is out: an unacknowledged message is sent again. */
	mailbox_post(m->mailbox, &n);
}

static void on_connect(struct mosquitto *mosq, void *data, int rc)
{
	if (rc == 0)
		post(data, NOTE_UP, 0, NULL);
	else
		post(data, NOTE_DOWN, 0, mosquitto_connack_string(rc));
}

static void on_disconnect(struct mosquitto *mosq, void *data, int rc)
{
	post(data, NOTE_DOWN, 0, rc == 0 ? "disconnected" : mosquitto_strerror(rc));
}

static void on_publish(struct mosquitto *mosq, void *data, int mid)
{
	post(data, NOTE_ACK, mid, NULL);
}

/* Sleeps s seconds unless mqtt_free() wakes it: true when stopping. */
static bool wait_or_stop(struct mqtt *m, int s)
{
	struct timespec until;
	bool stop;

	clock_gettime(CLOCK_REALTIME, &until);
	until.tv_sec += s;
	pthread_mutex_lock(&m->lock);
	while (!m->stopping && pthread_cond_timedwait(&m->cond, &m->lock, &until) == 0)
		;
	stop = m->stopping;
	pthread_mutex_unlock(&m->lock);
	return stop;
}

static bool stopping(struct mqtt *m)
{
	bool s;

	pthread_mutex_lock(&m->lock);
	s = m->stopping;
	pthread_mutex_unlock(&m->lock);
	return s;
}

/* libmosquitto's thread: connect, then its loop, which reconnects by
 * itself once connected; the first connection is tried again here. */
static void *mqtt_thread(void *data)
{
	struct mqtt *m = data;
	int delay = 1;

	while (!stopping(m)) {
		int rc = mosquitto_connect(m->mosq, m->host, m->port, KEEPALIVE_S);

		if (rc != MOSQ_ERR_SUCCESS) {
			post(m, NOTE_DOWN, 0, rc == MOSQ_ERR_ERRNO ? strerror(errno)
							        : mosquitto_strerror(rc));
			if (wait_or_stop(m, delay))
				break;
			delay = delay * 2 > RECONNECT_MAX_S ? RECONNECT_MAX_S : delay * 2;
			continue;
		}
		delay = 1;
		mosquitto_loop_forever(m->mosq, 1000, 1);
		if (!stopping(m) && wait_or_stop(m, 1))
			break;
	}
	return NULL;
}

/* ------------------------------------------------------ the loop's side */

static void forget_unconfirmed(struct mqtt *m)
{
	/* Whatever was in flight is published again by its owner once the
	 * link is back (outbox_reset()): the old ids no longer count. */
	m->n_inflight = 0;
}

static void take_ack(struct mqtt *m, int mid)
{
	for (size_t i = 0; i < m->n_inflight; i++) {
		struct inflight f = m->inflight[i];
		if (f.mid != mid)
			continue;
		m->inflight[i] = m->inflight[--m->n_inflight];
		if (f.tag > 0 && m->acked)
			m->acked(m->data, f.tag);
		return;
	}
}

static void on_note(void *msg, void *data)
{
	struct mqtt *m = data;
	const struct note *nt = msg;

	switch (nt->kind) {
	case NOTE_ACK:
		take_ack(m, nt->mid);
		break;
	case NOTE_UP:
		m->up = true;
		m->told_down = false;
		forget_unconfirmed(m);
		if (m->link)
			m->link(m->data, true, NULL);
		break;
	case NOTE_DOWN:
		/* Once per outage, not at every try to reconnect. */
		if ((m->up || !m->told_down) && m->link)
			m->link(m->data, false, nt->why);
		m->told_down = true;
		m->up = false;
		forget_unconfirmed(m);
		break;
	}
}

static int setup_client(struct mqtt *m, const struct mqtt_setup *setup, struct asph_error *err)
{
	const struct settings_mqtt *cfg = setup->cfg;
	const struct mqtt_credentials *cr = setup->credentials;
	int rc;

	m->mosq = mosquitto_new(setup->client_id, true, m);
	if (!m->mosq)
		return asph_error_set(err, -errno ? -errno : -ENOMEM, "mqtt: cannot make a client: %s",
				      strerror(errno ? errno : ENOMEM));
	mosquitto_threaded_set(m->mosq, true);
	mosquitto_connect_callback_set(m->mosq, on_connect);
	mosquitto_disconnect_callback_set(m->mosq, on_disconnect);
	mosquitto_publish_callback_set(m->mosq, on_publish);
	mosquitto_reconnect_delay_set(m->mosq, 1, RECONNECT_MAX_S, true);
	rc = mosquitto_will_set(m->mosq, setup->will_topic, (int)strlen(setup->will_payload),
				setup->will_payload, cfg->qos, true);
	if (rc == MOSQ_ERR_SUCCESS && cr && cr->username)
		rc = mosquitto_username_pw_set(m->mosq, cr->username, cr->password);
	if (rc == MOSQ_ERR_SUCCESS && cfg->tls) {
		if (cfg->ca_file)
			rc = mosquitto_tls_set(m->mosq, cfg->ca_file, NULL, cr ? cr->certfile : NULL,
					       cr ? cr->keyfile : NULL, NULL);
		else
			rc = mosquitto_int_option(m->mosq, MOSQ_OPT_TLS_USE_OS_CERTS, 1);
		if (rc == MOSQ_ERR_SUCCESS && !cfg->ca_file && cr && cr->certfile)
			rc = mosquitto_tls_set(m->mosq, NULL, "/etc/ssl/certs", cr->certfile,
					       cr->keyfile, NULL);
	}
	if (rc != MOSQ_ERR_SUCCESS)
		return asph_error_set(err, -EINVAL, "mqtt: %s", mosquitto_strerror(rc));
	return 0;
}

int mqtt_new(const struct mqtt_setup *setup, struct mqtt **out, struct asph_error *err)
{
	struct mqtt *m = calloc(1, sizeof(*m));
	int r;

	if (!m)
		return asph_error_set(err, -ENOMEM, "out of memory");
	pthread_mutex_init(&m->lock, NULL);
	pthread_cond_init(&m->cond, NULL);
	m->acked = setup->acked;
	m->link = setup->link;
	m->data = setup->data;
	m->port = setup->cfg->port;
	m->host = strdup(setup->cfg->host);
	m->will_topic = strdup(setup->will_topic);
	mosquitto_lib_init();
	r = m->host && m->will_topic ? setup_client(m, setup, err) : asph_error_set(err, -ENOMEM, "out of memory");
	if (r == 0) {
		r = mailbox_new(&(struct mailbox_setup){
				.event = setup->event, .size = sizeof(struct note),
				.deliver = on_note, .data = m }, &m->mailbox);
		if (r < 0)
			asph_error_set(err, r, "mqtt: %s", strerror(-r));
	}
	if (r == 0) {
		r = -pthread_create(&m->thread, NULL, mqtt_thread, m);
		if (r < 0)
			asph_error_set(err, r, "mqtt: cannot start its thread: %s", strerror(-r));
		m->thread_started = r == 0;
	}
	if (r < 0) {
		mqtt_free(m, NULL);
		return r;
	}
	*out = m;
	return 0;
}

/* Waits until the goodbye is out, at most GOODBYE_WAIT_NS. */
static void wait_goodbye(struct mqtt *m)
{
	struct timespec until;

	clock_gettime(CLOCK_REALTIME, &until);
	until = timespec_from_ns(ns_from_timespec(&until) + GOODBYE_WAIT_NS);
	pthread_mutex_lock(&m->lock);
	while (!m->goodbye_done && pthread_cond_timedwait(&m->cond, &m->lock, &until) == 0)
		;
	pthread_mutex_unlock(&m->lock);
}

static void stop_thread(struct mqtt *m)
{
	struct timespec until;

	pthread_mutex_lock(&m->lock);
	m->stopping = true;
	pthread_cond_broadcast(&m->cond);
	pthread_mutex_unlock(&m->lock);
	mosquitto_disconnect(m->mosq);
	clock_gettime(CLOCK_REALTIME, &until);
	until.tv_sec += JOIN_WAIT_S;
	/* A connect to a host that does not answer may take long: the
	 * process is ending, and the thread is left to it. */
	if (pthread_timedjoin_np(m->thread, NULL, &until) != 0) {
		log_warning("mqtt: the connection to %s:%d did not end in %d s; leaving it",
			    m->host, m->port, JOIN_WAIT_S);
		pthread_detach(m->thread);
		m->mosq = NULL;
	}
}

void mqtt_free(struct mqtt *m, const char *goodbye)
{
	if (!m)
		return;
	if (m->thread_started) {
		if (goodbye && m->up && m->mosq) {
			int mid = 0;
			/* the will's topic and QoS are the client's: its status */
			pthread_mutex_lock(&m->lock);
			if (mosquitto_publish(m->mosq, &mid, m->will_topic, (int)strlen(goodbye), goodbye,
					      1, true) == MOSQ_ERR_SUCCESS)
				m->goodbye_mid = mid;
			else
				m->goodbye_done = true;
			pthread_mutex_unlock(&m->lock);
			wait_goodbye(m);
		}
		stop_thread(m);
	}
	mailbox_free(m->mailbox);
	if (m->mosq)
		mosquitto_destroy(m->mosq);
	mosquitto_lib_cleanup();
	pthread_mutex_destroy(&m->lock);
	pthread_cond_destroy(&m->cond);
	free(m->inflight);
	free(m->will_topic);
	free(m->host);
	free(m);
}

int mqtt_publish(struct mqtt *m, const char *topic, const char *payload, int qos, bool retain,
		 int64_t tag)
{
	int mid = 0, rc;

	if (!m->up)
		return -ENOTCONN;
	if (m->n_inflight == m->cap_inflight) {
		size_t cap = m->cap_inflight ? 2 * m->cap_inflight : 64;
		struct inflight *f = realloc(m->inflight, cap * sizeof(*f));
		if (!f)
			return -ENOMEM;
		m->inflight = f;
		m->cap_inflight = cap;
	}
	rc = mosquitto_publish(m->mosq, &mid, topic, (int)strlen(payload), payload, qos, retain);
	if (rc == MOSQ_ERR_NO_CONN || rc == MOSQ_ERR_CONN_LOST)
		return -ENOTCONN;
	if (rc == MOSQ_ERR_NOMEM)
		return -ENOMEM;
	if (rc != MOSQ_ERR_SUCCESS) {
		log_warning("mqtt: cannot publish on %s: %s", topic, mosquitto_strerror(rc));
		return -EINVAL;
	}
	/* Recorded before the loop can read its acknowledgement: the note is
	 * read on this thread, later. */
	m->inflight[m->n_inflight++] = (struct inflight){ .mid = mid, .tag = tag, .qos = qos };
	return 0;
}

bool mqtt_up(const struct mqtt *m)
{
	return m->up;
}

size_t mqtt_pending(const struct mqtt *m)
{
	return m->n_inflight;
}
