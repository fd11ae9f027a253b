/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <arpa/inet.h>
#include <errno.h>
#include <limits.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>
#include <libpq-fe.h>

#include "asph-proto.h"
#include "settings.h"
#include "jsonpos.h"
#include "util-mem.h"

struct loader {
	const char *source;
	const char *text;
	size_t len;
	settings_error_fn report;
	void *data;
	int n_errors;
	uint64_t limits_given;          /* bit i: the limit of rows[i] is in the file */
};

static void complain(struct loader *ld, const char *field, const char *fmt, ...)
	__attribute__((format(printf, 3, 4)));

static void complain(struct loader *ld, const char *field, const char *fmt, ...)
{
	struct json_source src = { ld->text, ld->len, ld->source };
	struct asph_error e;
	va_list ap;

	asph_error_clear(&e);
	va_start(ap, fmt);
	asph_error_vset_at(&e, -EINVAL, NULL, 0, 0, NULL, fmt, ap);
	va_end(ap);
	json_error_locate(&e, -EINVAL, &src, field);
	ld->n_errors++;
	if (ld->report)
		ld->report(&e, ld->data);
}

static const struct settings_limits default_limits = {
	.max_clients = 256,
	.max_clients_per_user = 32,
	.reserved_clients = 8,
	.max_request_bytes = 1u << 20,
	.max_response_bytes = 4u << 20,
	.max_output_bytes = 8u << 20,
	.max_queue = 10000,
	.max_plan_points = 5000000,
	.max_plan_point_terms = 64000000,
	.max_subscriptions = 64,
	.max_subscriptions_per_user = 8,
	.reserved_subscriptions = 8,
	.request_timeout_ms = 30000,
	.auth_timeout_ms = 10000,
	.idle_timeout_ms = 600000,
	.progress_interval_ms = 250,
	.max_label_bytes = 256,
	.max_measured_bytes = 256u << 20,
	.min_free_disk_mb = 64,
};

static const struct settings_health default_health = {
	.sink_down_s = 60,
	.outbox_age_s = 600,
};

int settings_defaults(struct settings **out)
{
	struct settings *c = calloc(1, sizeof(*c));

	if (!c)
		return -ENOMEM;
	c->socket_path = strdup(PROTO_DEFAULT_SOCKET);
	c->state_dir = strdup(SETTINGS_STATE_DIR);
	if (!c->socket_path || !c->state_dir) {
		settings_free(c);
		return -ENOMEM;
	}
	c->socket_mode = 0660;
	c->limits = default_limits;
	c->health = default_health;
	*out = c;
	return 0;
}

void settings_free(struct settings *c)
{
	if (!c)
		return;
	free(c->source);
	free(c->socket_path);
	free(c->socket_group);
	free(c->operator_group);
	free(c->tcp_listen);
	free(c->tcp_host);
	free(c->tcp_port);
	free(c->token_file);
	free(c->http_listen);
	free(c->http_host);
	free(c->http_port);
	free(c->http_root);
	for (size_t i = 0; c->http_allowed_hosts && c->http_allowed_hosts[i]; i++)
		free(c->http_allowed_hosts[i]);
	free(c->http_allowed_hosts);
	free(c->http_trust_proxy);
	free(c->state_dir);
	free(c->instruments_json);
	free(c->text);
	settings_mqtt_free(c->mqtt);
	settings_postgres_free(c->postgres);
	free(c);
}

void settings_mqtt_free(struct settings_mqtt *m)
{
	if (!m)
		return;
	free(m->url);
	free(m->host);
	free(m->prefix);
	free(m->client_id);
	free(m->credentials_file);
	free(m->ca_file);
	free(m);
}

void settings_postgres_free(struct settings_postgres *p)
{
	if (!p)
		return;
	free(p->conninfo);
	free(p->password_file);
	free(p);
}

static void take_string(struct loader *ld, json_t *v, const char *field,
			char **dst, bool absolute_path)
{
	if (!json_is_string(v) || json_string_length(v) == 0 ||
	    strlen(json_string_value(v)) != json_string_length(v)) {
		complain(ld, field, "must be a non-empty string");
		return;
	}
	if (absolute_path && json_string_value(v)[0] != '/') {
		complain(ld, field, "must be an absolute path");
		return;
	}
	free(*dst);
	*dst = strdup(json_string_value(v));
}

static void take_mode(struct loader *ld, json_t *v, mode_t *dst)
{
	const char *s = json_string_value(v);
	char *end;
	unsigned long m;

	if (!s || !*s) {
		complain(ld, "socket_mode", "must be an octal string such as \"0660\"");
		return;
	}
	errno = 0;
	m = strtoul(s, &end, 8);
	if (errno || *end || m > 0777 || (m & 0002)) {
		complain(ld, "socket_mode",
			 "must be octal, at most 0777 and not writable by others");
		return;
	}
	*dst = (mode_t)m;
}

static bool given(const struct loader *ld, const char *name);

/* The default of a limit bounded by another the file set, scaled down. */
static void derive(const struct loader *ld, const char *name, uint32_t *v, uint32_t bound)
{
	if (!given(ld, name) && *v > bound)
		*v = bound;
}

/* The limits that bound each other: a default follows a smaller limit the
 * file sets; a value the file sets must fit. */
static void check_limit_pairs(struct loader *ld, struct settings_limits *l)
{
	derive(ld, "reserved_clients", &l->reserved_clients, l->max_clients / 4);
	derive(ld, "reserved_subscriptions", &l->reserved_subscriptions,
	       l->max_subscriptions / 4);
	derive(ld, "max_response_bytes", &l->max_response_bytes, l->max_output_bytes / 2);
	if (l->reserved_clients >= l->max_clients)
		complain(ld, "limits.reserved_clients", "must be less than limits.max_clients "
			 "(%u), or nobody but operators could connect", l->max_clients);
	if (l->reserved_subscriptions >= l->max_subscriptions)
		complain(ld, "limits.reserved_subscriptions", "must be less than "
			 "limits.max_subscriptions (%u)", l->max_subscriptions);
	if (l->max_response_bytes > l->max_output_bytes / 2)
		complain(ld, "limits.max_response_bytes", "must be at most half of "
			 "limits.max_output_bytes (%u): a line's answers wait in the output",
			 l->max_output_bytes / 2);
}

/* "HOST:PORT", "[IPV6]:PORT": a host and a port number (0 picks one),
 * of tcp_listen or http_listen (field) into *listen, *host_out, *port_out. */
static void take_listen(struct loader *ld, json_t *v, const char *field, char **listen,
			char **host_out, char **port_out)
{
	const char *text, *colon, *host;
	size_t host_len;
	char *end;
	unsigned long port;

	take_string(ld, v, field, listen, false);
	text = json_string_value(v);
	if (!*listen || !text)
		return;
	colon = strrchr(text, ':');
	if (!colon) {
		complain(ld, field, "must be HOST:PORT (a host name or address, a colon, "
			 "a port number)");
		return;
	}
	host = text;
	host_len = (size_t)(colon - text);
	if (host_len >= 2 && host[0] == '[' && host[host_len - 1] == ']') {
		host++;
		host_len -= 2;
	}
	errno = 0;
	port = strtoul(colon + 1, &end, 10);
	if (host_len == 0 || colon[1] < '0' || colon[1] > '9' || *end || errno || port > 65535) {
		complain(ld, field, "must be HOST:PORT with a host and a port number "
			 "from 0 to 65535, not \"%s\"", text);
		return;
	}
	free(*host_out);
	free(*port_out);
	*host_out = strndup(host, host_len);
	*port_out = strdup(colon + 1);
}

/*
 * "mqtt://HOST[:PORT]" or "mqtts://HOST[:PORT]" (an IPv6 address in
 * brackets), nothing after the port: user and password come from the
 * credentials file, never from the configuration.
 */
static void take_broker_url(struct loader *ld, json_t *v, struct settings_mqtt *m)
{
	const char *text, *host, *end, *p;
	unsigned long port;
	char *stop;

	take_string(ld, v, "mqtt.url", &m->url, false);
	if (!m->url)
		return;
	text = m->url;
	if (!strncmp(text, "mqtt://", 7)) {
		host = text + 7;
	} else if (!strncmp(text, "mqtts://", 8)) {
		host = text + 8;
		m->tls = true;
	} else {
		complain(ld, "mqtt.url", "must start with mqtt:// or mqtts://, not \"%.64s\"", text);
		return;
	}
	if (strchr(host, '@')) {
		complain(ld, "mqtt.url", "must not hold a user or password: they go in "
			 "mqtt.credentials_file");
		return;
	}
	if (host[0] == '[') {
		end = strchr(host, ']');
		if (!end || end == host + 1) {
			complain(ld, "mqtt.url", "an IPv6 address needs its closing ']'");
			return;
		}
		m->host = strndup(host + 1, (size_t)(end - host - 1));
		p = end + 1;
	} else {
		p = host + strcspn(host, ":/?#");
		if (p == host) {
			complain(ld, "mqtt.url", "has no host");
			return;
		}
		m->host = strndup(host, (size_t)(p - host));
	}
	m->port = m->tls ? 8883 : 1883;
	if (*p == ':') {
		errno = 0;
		port = strtoul(p + 1, &stop, 10);
		if (p[1] < '0' || p[1] > '9' || errno || port < 1 || port > 65535) {
			complain(ld, "mqtt.url", "the port must be a number from 1 to 65535");
			return;
		}
		m->port = (int)port;
		p = stop;
	}
	if (*p == '/')
		p++;
	if (*p)
		complain(ld, "mqtt.url", "must end after the host and port, not with \"%.64s\"", p);
}

/* A topic prefix: topic levels without wildcards, not starting or ending
 * with '/'. */
static void take_prefix(struct loader *ld, json_t *v, struct settings_mqtt *m)
{
	const char *p;

	take_string(ld, v, "mqtt.prefix", &m->prefix, false);
	p = m->prefix;
	if (!p)
		return;
	if (strpbrk(p, "+#") || p[0] == '/' || p[strlen(p) - 1] == '/' || strstr(p, "//") ||
	    strlen(p) > 200)
		complain(ld, "mqtt.prefix", "must be topic levels such as \"lab/asphd/bench1\": no "
			 "'+' or '#', no empty level, at most 200 bytes");
}

/* ------------------------------------------------------------ the table */

/*
 * How a row takes its value v (named field in messages) into base: the
 * settings, or the section's structure (struct settings_limits,
 * struct settings_mqtt, struct settings_postgres).
 */
struct row;
typedef void (*take_fn)(struct loader *ld, void *base, const struct row *row, const char *field,
			json_t *v);

struct row {
	const char *name;       /* "socket", "limits.max_queue", "mqtt.url" */
	const char *type;       /* what it takes, for people (a limit's: from min, max) */
	const char *fallback;   /* the default, for people (a limit's: default_limits) */
	const char *help;
	take_fn take;
	size_t offset;          /* of the member of base that a plain row sets */
	uint32_t min, max;      /* a limit's range */
};

#define AT(type, member) offsetof(type, member)

static void take_path(struct loader *ld, void *base, const struct row *row, const char *field,
		      json_t *v)
{
	take_string(ld, v, field, (char **)((char *)base + row->offset), true);
}

static void take_text(struct loader *ld, void *base, const struct row *row, const char *field,
		      json_t *v)
{
	char **dst = (char **)((char *)base + row->offset);

	take_string(ld, v, field, dst, false);
	if (row->max && *dst && strlen(*dst) > row->max)
		complain(ld, field, "must be at most %u bytes", row->max);
}

static void take_socket_mode(struct loader *ld, void *base, const struct row *row,
			     const char *field, json_t *v)
{
	take_mode(ld, v, &((struct settings *)base)->socket_mode);
}

static void take_tcp_listen(struct loader *ld, void *base, const struct row *row,
			    const char *field, json_t *v)
{
	struct settings *c = base;

	take_listen(ld, v, field, &c->tcp_listen, &c->tcp_host, &c->tcp_port);
}

static void take_http_listen(struct loader *ld, void *base, const struct row *row,
			     const char *field, json_t *v)
{
	struct settings *c = base;

	take_listen(ld, v, field, &c->http_listen, &c->http_host, &c->http_port);
}

/* A host name or address as a browser sends it in Host, without the
 * port (an IPv6 address without its brackets). */
static bool host_name(const char *s)
{
	struct in6_addr a6;

	if (!*s || strlen(s) > 253 || strpbrk(s, " \t/[]@?#"))
		return false;
	return !strchr(s, ':') || inet_pton(AF_INET6, s, &a6) == 1;
}

static void take_allowed_hosts(struct loader *ld, void *base, const struct row *row,
			       const char *field, json_t *v)
{
	struct settings *c = base;
	size_t i, n = json_array_size(v);
	json_t *h;

	if (!json_is_array(v) || n == 0) {
		complain(ld, field, "must be a non-empty array of host names");
		return;
	}
	c->http_allowed_hosts = calloc(n + 1, sizeof(char *));
	if (!c->http_allowed_hosts)
		return;
	json_array_foreach(v, i, h) {
		if (!json_is_string(h) || !host_name(json_string_value(h))) {
			complain(ld, field, "[%zu] must be a host name or address without a port, "
				 "such as \"metrology.lab.example\"", i);
			continue;
		}
		c->http_allowed_hosts[i] = strdup(json_string_value(h));
	}
}

static void take_proxy(struct loader *ld, void *base, const struct row *row, const char *field,
		       json_t *v)
{
	struct settings *c = base;
	struct in6_addr a;

	take_string(ld, v, field, &c->http_trust_proxy, false);
	if (c->http_trust_proxy && inet_pton(AF_INET, c->http_trust_proxy, &a) != 1 &&
	    inet_pton(AF_INET6, c->http_trust_proxy, &a) != 1)
		complain(ld, field, "must be the proxy's IP address, such as \"127.0.0.1\"");
}

static void take_limit(struct loader *ld, void *base, const struct row *row, const char *field,
		       json_t *v);
static void take_section(struct loader *ld, void *base, const struct row *row,
			 const char *field, json_t *v);
static void take_mqtt(struct loader *ld, void *base, const struct row *row, const char *field,
		      json_t *v);
static void take_seconds(struct loader *ld, void *base, const struct row *row,
			 const char *field, json_t *v);
static void take_postgres(struct loader *ld, void *base, const struct row *row,
			  const char *field, json_t *v);
static void take_instruments(struct loader *ld, void *base, const struct row *row,
			     const char *field, json_t *v);

static void take_url(struct loader *ld, void *base, const struct row *row, const char *field,
		     json_t *v)
{
	take_broker_url(ld, v, base);
}

static void take_topic_prefix(struct loader *ld, void *base, const struct row *row,
			      const char *field, json_t *v)
{
	take_prefix(ld, v, base);
}

static void take_qos(struct loader *ld, void *base, const struct row *row, const char *field,
		     json_t *v)
{
	if (!json_is_integer(v) || json_integer_value(v) < 0 || json_integer_value(v) > 2)
		complain(ld, field, "must be 0, 1 or 2");
	else
		((struct settings_mqtt *)base)->qos = (int)json_integer_value(v);
}

#define LIMIT(n, lo, hi, text) { .name = "limits." #n, .take = take_limit, \
	.offset = AT(struct settings_limits, n), .min = lo, .max = hi, .help = text }

/* Every setting of the file, in the order of the reference (asphd
 * --list-settings, docs/admin.md): the file is read through this table,
 * so a setting the daemon takes has its row here. */
static const struct row rows[] = {
	{ "socket", "path", PROTO_DEFAULT_SOCKET, "the unix socket, when the daemon binds it "
	  "itself (not socket-activated by systemd)", take_path, AT(struct settings, socket_path) },
	{ "socket_group", "group name", "the daemon's group", "the group of a socket the daemon "
	  "binds", take_text, AT(struct settings, socket_group) },
	{ "socket_mode", "octal mode", "\"0660\"", "the mode of a socket the daemon binds; never "
	  "writable by others", take_socket_mode },
	{ "operator_group", "group name", "none: only root operates", "its members (and root) "
	  "may submit, cancel, pause, resume, re-queue, reorder and lock", take_text,
	  AT(struct settings, operator_group) },
	{ "state_dir", "path", SETTINGS_STATE_DIR " (systemd's $STATE_DIRECTORY)", "the job store, "
	  "its backups, the scans and the results", take_path, AT(struct settings, state_dir) },
	{ "tcp_listen", "HOST:PORT", "off", "a TCP listener for clients that send an API token "
	  "(docs/daemon.md)", take_tcp_listen },
	{ "http_listen", "HOST:PORT", "off", "the web page and its API (docs/web.md), /healthz "
	  "and /metrics (docs/admin.md)", take_http_listen },
	{ "http_root", "path", "none: the page built into asphd", "a folder of the web page's "
	  "files, served instead of the built-in page; none that others than root and the "
	  "daemon's user may write", take_path, AT(struct settings, http_root) },
	{ "http_allowed_hosts", "array of host names", "the listen address, localhost and the "
	  "host name", "the names the web page answers to (Host): others get 421 (DNS "
	  "rebinding)", take_allowed_hosts },
	{ "http_trust_proxy", "IP address", "none", "the reverse proxy whose X-Forwarded-For and "
	  "X-Forwarded-Proto are believed (the browser's address, a Secure cookie)",
	  take_proxy },
	{ "token_file", "path", "none", "deprecated: a file holding one admin token for TCP "
	  "clients; named tokens replace it", take_path, AT(struct settings, token_file) },
	{ "limits", "object", "the defaults below", "what one client, one user and the disk may "
	  "take (proto/README.md, Limits)", take_section, AT(struct settings, limits) },
	LIMIT(max_clients, 1, 65536, "connections and web sessions in all (needs LimitNOFILE=: "
	      "checked at the start); root has 4 of its own beyond it"),
	LIMIT(max_clients_per_user, 1, 65536, "connections of one uid (root excepted), over TCP "
	      "or the web of one address; web sessions of one address and of one token"),
	LIMIT(reserved_clients, 0, 65535, "the last connections and sessions of max_clients, "
	      "kept for root, the operator group and operator or admin tokens (default at most "
	      "a quarter of max_clients)"),
	LIMIT(max_request_bytes, 1024, 64u << 20, "one request line"),
	LIMIT(max_response_bytes, 4096, 512u << 20, "the answers to one line; at most half of "
	      "max_output_bytes"),
	LIMIT(max_output_bytes, 65536, 1u << 30, "a client's unread output"),
	LIMIT(max_queue, 1, 10000000, "jobs queued, running, paused or interrupted"),
	LIMIT(max_plan_points, 10, 100000000, "the points of one plan"),
	LIMIT(max_plan_point_terms, 1000, 4000000000u, "one plan's points times its surface's "
	      "terms: what checking and estimating it costs"),
	LIMIT(max_subscriptions, 1, 65536, "clients subscribed to events"),
	LIMIT(max_subscriptions_per_user, 1, 65536, "subscriptions of one uid, address or named "
	      "token"),
	LIMIT(reserved_subscriptions, 0, 65535, "the last subscriptions, kept for operators "
	      "(default at most a quarter of max_subscriptions)"),
	LIMIT(request_timeout_ms, 100, 3600000, "an incomplete request line or web body; output "
	      "the client does not read; a plan's check and estimate, a scan read for the page"),
	LIMIT(auth_timeout_ms, 100, 3600000, "a TCP client without hello and its token; a web "
	      "connection without a request's head"),
	LIMIT(idle_timeout_ms, 0, 86400000, "a client that sends nothing and is not subscribed; "
	      "a web session unused without an event stream (0: none)"),
	LIMIT(progress_interval_ms, 10, 60000, "between two progress events of a job"),
	LIMIT(max_label_bytes, 16, 4096, "a job's label"),
	LIMIT(max_measured_bytes, 1024, 4000000000u, "the measured data file of one job.submit "
	      "(\"measured\"), copied into the job's folder"),
	LIMIT(min_free_disk_mb, 0, 1048576, "MiB kept free on the state directory: jobs and "
	      "backups that would not leave it are refused (0: no check)"),
	{ "health", "object", "the defaults below", "when the daemon's health is degraded "
	  "(docs/admin.md, Health)", take_section, AT(struct settings, health) },
	{ "health.sink_down_s", .take = take_seconds, .offset = AT(struct settings_health,
	  sink_down_s), .min = 1, .max = 86400, .help = "seconds the MQTT broker or the database "
	  "may be out of reach before the health says sink_down" },
	{ "health.outbox_age_s", .take = take_seconds, .offset = AT(struct settings_health,
	  outbox_age_s), .min = 1, .max = 604800, .help = "seconds a sink's oldest message may "
	  "wait in the outbox before the health says outbox_backlog" },
	{ "mqtt", "object", "off", "MQTT telemetry to a broker (docs/fleet.md)", take_mqtt },
	{ "mqtt.url", "mqtt://HOST[:PORT] or mqtts://HOST[:PORT]", "none: needed",
	  "the broker; no user or password in it", take_url },
	{ "mqtt.prefix", "topic levels", "asphd/HOSTNAME", "the topics' prefix, without "
	  "wildcards", take_topic_prefix },
	{ "mqtt.client_id", "text", "asphd-HOSTNAME-ID", "the MQTT client id (at most 128 bytes)",
	  take_text, AT(struct settings_mqtt, client_id), 0, 128 },
	{ "mqtt.qos", "0, 1 or 2", "1", "the QoS of the job states and results", take_qos },
	{ "mqtt.credentials_file", "path", "none", "a JSON file with the broker's username and password (docs/fleet.md)",
	  take_path, AT(struct settings_mqtt, credentials_file) },
	{ "mqtt.ca_file", "path", "the system's CAs", "the CA of an mqtts:// broker",
	  take_path, AT(struct settings_mqtt, ca_file) },
	{ "postgres", "object", "off", "the central results store in PostgreSQL (docs/fleet.md)",
	  take_postgres },
	{ "postgres.conninfo", "libpq connection string", "none: needed", "the database, "
	  "without its password", take_text, AT(struct settings_postgres, conninfo) },
	{ "postgres.password_file", "path", "none (~/.pgpass, PGPASSWORD)", "a file with the "
	  "database password", take_path, AT(struct settings_postgres, password_file) },
	{ "instruments", "array", "one \"mock\" instrument", "each a stage and a probe, a driver "
	  "and its options each (docs/drivers.md)", take_instruments },
};

#undef LIMIT

/* The row of field ("limits.max_queue"), or NULL. */
static const struct row *find_row(const char *field)
{
	for (size_t i = 0; i < ARRAY_SIZE(rows); i++)
		if (!strcmp(rows[i].name, field))
			return &rows[i];
	return NULL;
}

/* "url, prefix, ...": the members section takes, for a message. */
static void members_of(const char *section, char *buf, size_t size)
{
	size_t n = strlen(section), used = 0;

	buf[0] = '\0';
	for (size_t i = 0; i < ARRAY_SIZE(rows) && used < size; i++)
		if (!strncmp(rows[i].name, section, n) && rows[i].name[n] == '.')
			used += (size_t)snprintf(buf + used, size - used, "%s%s", used ? ", " : "",
						 rows[i].name + n + 1);
}

/*
 * Each member of obj, a section (NULL: the top level), taken into base by
 * its row; a member without one is an unknown setting. A name with a dot
 * is never a section's member.
 */
static void take_members(struct loader *ld, void *base, const char *section, json_t *obj)
{
	const char *key;
	json_t *v;

	json_object_foreach(obj, key, v) {
		char field[96], members[256];
		const struct row *row;

		snprintf(field, sizeof(field), "%s%s%.60s", section ? section : "", section ? "." : "",
			 key);
		row = strchr(key, '.') ? NULL : find_row(field);
		if (row) {
			row->take(ld, base, row, field, v);
		} else if (!section) {
			complain(ld, field, "unknown setting");
		} else if (!strcmp(section, "limits")) {
			complain(ld, field, "unknown limit");
		} else {
			members_of(section, members, sizeof(members));
			complain(ld, field, "unknown setting (%s takes %s)", section, members);
		}
	}
}

/* An integer of [row->min, row->max] at row->offset of base. 0, or -1
 * having complained. */
static int take_integer(struct loader *ld, void *base, const struct row *row, const char *field,
			json_t *v)
{
	if (!json_is_integer(v) || json_integer_value(v) < row->min ||
	    json_integer_value(v) > row->max) {
		complain(ld, field, "must be an integer in [%u, %u]", row->min, row->max);
		return -1;
	}
	*(uint32_t *)((char *)base + row->offset) = (uint32_t)json_integer_value(v);
	return 0;
}

static bool given(const struct loader *ld, const char *name)
{
	char field[96];
	const struct row *row;

	snprintf(field, sizeof(field), "limits.%s", name);
	row = find_row(field);
	return row && ld->limits_given & (1ull << (row - rows));
}

static void take_limit(struct loader *ld, void *base, const struct row *row, const char *field,
		       json_t *v)
{
	if (take_integer(ld, base, row, field, v) == 0)
		ld->limits_given |= 1ull << (row - rows);
}

static void take_seconds(struct loader *ld, void *base, const struct row *row,
			 const char *field, json_t *v)
{
	take_integer(ld, base, row, field, v);
}

/* A section whose structure is a member of the settings (row->offset). */
static void take_section(struct loader *ld, void *base, const struct row *row,
			 const char *field, json_t *v)
{
	if (!json_is_object(v)) {
		complain(ld, field, "must be an object");
		return;
	}
	take_members(ld, (char *)base + row->offset, field, v);
}

static void take_mqtt(struct loader *ld, void *base, const struct row *row, const char *field,
		      json_t *v)
{
	struct settings *c = base;

	if (!json_is_object(v)) {
		complain(ld, field, "must be an object");
		return;
	}
	settings_mqtt_free(c->mqtt);
	c->mqtt = calloc(1, sizeof(*c->mqtt));
	if (!c->mqtt) {
		complain(ld, field, "out of memory");
		return;
	}
	c->mqtt->qos = 1;
	take_members(ld, c->mqtt, field, v);
	if (!json_object_get(v, "url"))
		complain(ld, field, "needs \"url\", the broker's mqtt:// or mqtts:// address");
	if (c->mqtt->ca_file && c->mqtt->url && !c->mqtt->tls)
		complain(ld, "mqtt.ca_file", "is for an mqtts:// broker; the url is mqtt://");
}

/* Whether a libpq connection string (key=value or a URI) gives a
 * password; one libpq cannot read is said so. */
static bool conninfo_has_password(struct loader *ld, const char *conninfo)
{
	char *why = NULL;
	PQconninfoOption *opts = PQconninfoParse(conninfo, &why);
	bool has = false;

	if (!opts) {
		complain(ld, "postgres.conninfo", "is not a libpq connection string: %.200s",
			 why ? why : "out of memory");
		PQfreemem(why);
		return false;
	}
	for (PQconninfoOption *o = opts; o->keyword; o++)
		has |= o->val && o->val[0] && strstr(o->keyword, "password");
	PQconninfoFree(opts);
	return has;
}

static void take_postgres(struct loader *ld, void *base, const struct row *row,
			  const char *field, json_t *v)
{
	struct settings *c = base;

	if (!json_is_object(v)) {
		complain(ld, field, "must be an object");
		return;
	}
	settings_postgres_free(c->postgres);
	c->postgres = calloc(1, sizeof(*c->postgres));
	if (!c->postgres) {
		complain(ld, field, "out of memory");
		return;
	}
	take_members(ld, c->postgres, field, v);
	if (!c->postgres->conninfo)
		complain(ld, field, "needs \"conninfo\", a libpq connection string such as "
			 "\"host=db.lab dbname=asph user=asphd\"");
	else if (conninfo_has_password(ld, c->postgres->conninfo))
		complain(ld, "postgres.conninfo", "must not hold the password (as password= or "
			 "in a URI's user:password@): it goes in postgres.password_file");
}

static void take_instruments(struct loader *ld, void *base, const struct row *row,
			     const char *field, json_t *v)
{
	struct settings *c = base;
	json_t *wrap;

	if (!json_is_array(v) || json_array_size(v) == 0) {
		complain(ld, field, "must be a non-empty array");
		return;
	}
	/* Kept as the drivers' own format for their parser. */
	free(c->instruments_json);
	wrap = json_pack("{s:O}", "instruments", v);
	c->instruments_json = wrap ? json_dumps(wrap, JSON_COMPACT) : NULL;
	json_decref(wrap);
}

size_t settings_count(void)
{
	return ARRAY_SIZE(rows);
}

void settings_describe(size_t i, struct setting_info *out)
{
	const struct row *row = &rows[i];

	out->name = row->name;
	out->help = row->help;
	if (row->take == take_limit || row->take == take_seconds) {
		const void *defaults = row->take == take_limit ? (const void *)&default_limits
							       : (const void *)&default_health;
		snprintf(out->type, sizeof(out->type), "integer from %u to %u", row->min, row->max);
		snprintf(out->fallback, sizeof(out->fallback), "%u",
			 *(const uint32_t *)((const char *)defaults + row->offset));
	} else {
		snprintf(out->type, sizeof(out->type), "%s", row->type);
		snprintf(out->fallback, sizeof(out->fallback), "%s", row->fallback);
	}
}

void settings_blank_comments(char *text, size_t len)
{
	bool in_string = false;

	for (size_t i = 0; i < len; i++) {
		if (in_string) {
			if (text[i] == '\\')
				i++;
			else if (text[i] == '"')
				in_string = false;
		} else if (text[i] == '"') {
			in_string = true;
		} else if (text[i] == '/' && i + 1 < len && text[i + 1] == '/') {
			for (; i < len && text[i] != '\n'; i++)
				text[i] = ' ';
		}
	}
}

int settings_load(const char *path, struct settings **out,
		settings_error_fn report, void *data)
{
	struct loader ld = { .source = path, .report = report, .data = data };
	struct settings *c = NULL;
	_cleanup_free_ char *text = NULL;
	json_error_t je;
	json_t *root;
	size_t len;
	int r;

	r = settings_defaults(&c);
	if (r < 0)
		return r;
	if (!path) {
		*out = c;
		return 0;
	}
	c->source = strdup(path);
	{
		_cleanup_fclose_ FILE *f = fopen(path, "re");
		if (!f) {
			r = -errno;
			struct asph_error e;
			asph_error_clear(&e);
			asph_error_set_at(&e, r, path, 0, 0, NULL, "cannot open: %s", strerror(-r));
			if (report)
				report(&e, data);
			settings_free(c);
			return r;
		}
		text = malloc(1u << 20);
		len = text ? fread(text, 1, 1u << 20, f) : 0;
		if (!text || len == 1u << 20 || ferror(f)) {
			complain(&ld, NULL, "cannot read, or larger than 1 MiB");
			settings_free(c);
			return -EINVAL;
		}
	}
	settings_blank_comments(text, len);
	ld.text = text;
	ld.len = len;
	root = json_loadb(text, len, JSON_REJECT_DUPLICATES, &je);
	if (!root) {
		struct asph_error e;
		asph_error_clear(&e);
		asph_error_set_at(&e, -EINVAL, path, je.line, je.column, NULL, "%s", je.text);
		if (report)
			report(&e, data);
		settings_free(c);
		return -EINVAL;
	}
	if (!json_is_object(root))
		complain(&ld, NULL, "the configuration must be a JSON object");
	else
		take_members(&ld, c, NULL, root);
	json_decref(root);
	check_limit_pairs(&ld, &c->limits);
	if (ld.n_errors) {
		settings_free(c);
		return -EINVAL;
	}
	c->text = steal_ptr(text);
	c->text_len = len;
	*out = c;
	return 0;
}

void settings_locate(const struct settings *s, const char *field, struct asph_error *err)
{
	struct json_source src = { s->text, s->text_len, s->source };

	json_error_locate(err, 0, &src, field);
}

void settings_vreport(const struct settings *s, const char *field, int code,
		      settings_error_fn report, void *data, const char *fmt, va_list ap)
{
	struct asph_error e;

	asph_error_clear(&e);
	e.code = code;
	vsnprintf(e.message, sizeof(e.message), fmt, ap);
	settings_locate(s, field, &e);
	if (report)
		report(&e, data);
}
