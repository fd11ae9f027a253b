/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <arpa/inet.h>
#include <errno.h>
#include <limits.h>
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
	uint64_t limits_given;          /* bit i: limit_fields[i] is in the file */
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
	.min_free_disk_mb = 64,
};

int settings_defaults(struct settings **out)
{
	struct settings *c = calloc(1, sizeof(*c));

	if (!c)
		return -ENOMEM;
	c->socket_path = strdup(PROTO_DEFAULT_SOCKET);
	c->state_dir = strdup("/var/lib/asphd");
	if (!c->socket_path || !c->state_dir) {
		settings_free(c);
		return -ENOMEM;
	}
	c->socket_mode = 0660;
	c->limits = default_limits;
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

static const struct {
	const char *name;
	size_t offset;
	uint32_t min, max;
} limit_fields[] = {
#define LIMIT(n, lo, hi) { #n, offsetof(struct settings_limits, n), lo, hi }
	LIMIT(max_clients, 1, 65536),
	LIMIT(max_clients_per_user, 1, 65536),
	LIMIT(reserved_clients, 0, 65535),
	LIMIT(max_request_bytes, 1024, 64u << 20),
	LIMIT(max_response_bytes, 4096, 512u << 20),
	LIMIT(max_output_bytes, 65536, 1u << 30),
	LIMIT(max_queue, 1, 10000000),
	LIMIT(max_plan_points, 10, 100000000),
	LIMIT(max_plan_point_terms, 1000, 4000000000u),
	LIMIT(max_subscriptions, 1, 65536),
	LIMIT(max_subscriptions_per_user, 1, 65536),
	LIMIT(reserved_subscriptions, 0, 65535),
	LIMIT(request_timeout_ms, 100, 3600000),
	LIMIT(auth_timeout_ms, 100, 3600000),
	LIMIT(idle_timeout_ms, 0, 86400000),
	LIMIT(progress_interval_ms, 10, 60000),
	LIMIT(max_label_bytes, 16, 4096),
	LIMIT(min_free_disk_mb, 0, 1048576),
#undef LIMIT
};

static void take_limits(struct loader *ld, json_t *obj, struct settings_limits *l)
{
	const char *key;
	json_t *v;
	char field[96];

	if (!json_is_object(obj)) {
		complain(ld, "limits", "must be an object");
		return;
	}
	json_object_foreach(obj, key, v) {
		size_t i;
		snprintf(field, sizeof(field), "limits.%.60s", key);
		for (i = 0; i < ARRAY_SIZE(limit_fields); i++)
			if (!strcmp(limit_fields[i].name, key))
				break;
		if (i == ARRAY_SIZE(limit_fields)) {
			complain(ld, field, "unknown limit");
			continue;
		}
		if (!json_is_integer(v) || json_integer_value(v) < limit_fields[i].min ||
		    json_integer_value(v) > limit_fields[i].max) {
			complain(ld, field, "must be an integer in [%u, %u]",
				 limit_fields[i].min, limit_fields[i].max);
			continue;
		}
		*(uint32_t *)((char *)l + limit_fields[i].offset) =
			(uint32_t)json_integer_value(v);
		ld->limits_given |= 1ull << i;
	}
}

static bool given(const struct loader *ld, const char *name)
{
	for (size_t i = 0; i < ARRAY_SIZE(limit_fields); i++)
		if (!strcmp(limit_fields[i].name, name))
			return ld->limits_given & (1ull << i);
	return false;
}

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

static void take_mqtt(struct loader *ld, json_t *obj, struct settings *c)
{
	const char *key;
	json_t *v;
	char field[96];

	if (!json_is_object(obj)) {
		complain(ld, "mqtt", "must be an object");
		return;
	}
	settings_mqtt_free(c->mqtt);
	c->mqtt = calloc(1, sizeof(*c->mqtt));
	if (!c->mqtt) {
		complain(ld, "mqtt", "out of memory");
		return;
	}
	c->mqtt->qos = 1;
	json_object_foreach(obj, key, v) {
		snprintf(field, sizeof(field), "mqtt.%.60s", key);
		if (!strcmp(key, "url"))
			take_broker_url(ld, v, c->mqtt);
		else if (!strcmp(key, "prefix"))
			take_prefix(ld, v, c->mqtt);
		else if (!strcmp(key, "client_id")) {
			take_string(ld, v, field, &c->mqtt->client_id, false);
			if (c->mqtt->client_id && strlen(c->mqtt->client_id) > 128)
				complain(ld, field, "must be at most 128 bytes");
		} else if (!strcmp(key, "qos")) {
			if (!json_is_integer(v) || json_integer_value(v) < 0 ||
			    json_integer_value(v) > 2)
				complain(ld, field, "must be 0, 1 or 2");
			else
				c->mqtt->qos = (int)json_integer_value(v);
		} else if (!strcmp(key, "credentials_file"))
			take_string(ld, v, field, &c->mqtt->credentials_file, true);
		else if (!strcmp(key, "ca_file"))
			take_string(ld, v, field, &c->mqtt->ca_file, true);
		else
			complain(ld, field, "unknown setting (mqtt takes url, prefix, client_id, "
				 "qos, credentials_file, ca_file)");
	}
	if (!json_object_get(obj, "url"))
		complain(ld, "mqtt", "needs \"url\", the broker's mqtt:// or mqtts:// address");
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

static void take_postgres(struct loader *ld, json_t *obj, struct settings *c)
{
	const char *key;
	json_t *v;
	char field[96];

	if (!json_is_object(obj)) {
		complain(ld, "postgres", "must be an object");
		return;
	}
	settings_postgres_free(c->postgres);
	c->postgres = calloc(1, sizeof(*c->postgres));
	if (!c->postgres) {
		complain(ld, "postgres", "out of memory");
		return;
	}
	json_object_foreach(obj, key, v) {
		snprintf(field, sizeof(field), "postgres.%.60s", key);
		if (!strcmp(key, "conninfo"))
			take_string(ld, v, field, &c->postgres->conninfo, false);
		else if (!strcmp(key, "password_file"))
			take_string(ld, v, field, &c->postgres->password_file, true);
		else
			complain(ld, field, "unknown setting (postgres takes conninfo and "
				 "password_file)");
	}
	if (!c->postgres->conninfo)
		complain(ld, "postgres", "needs \"conninfo\", a libpq connection string such as "
			 "\"host=db.lab dbname=asph user=asphd\"");
	else if (conninfo_has_password(ld, c->postgres->conninfo))
		complain(ld, "postgres.conninfo", "must not hold the password (as password= or "
			 "in a URI's user:password@): it goes in postgres.password_file");
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

static void take_allowed_hosts(struct loader *ld, json_t *v, struct settings *c)
{
	size_t i, n = json_array_size(v);
	json_t *h;

	if (!json_is_array(v) || n == 0) {
		complain(ld, "http_allowed_hosts", "must be a non-empty array of host names");
		return;
	}
	c->http_allowed_hosts = calloc(n + 1, sizeof(char *));
	if (!c->http_allowed_hosts)
		return;
	json_array_foreach(v, i, h) {
		if (!json_is_string(h) || !host_name(json_string_value(h))) {
			complain(ld, "http_allowed_hosts", "[%zu] must be a host name or address "
				 "without a port, such as \"metrology.lab.example\"", i);
			continue;
		}
		c->http_allowed_hosts[i] = strdup(json_string_value(h));
	}
}

static void take_proxy(struct loader *ld, json_t *v, struct settings *c)
{
	struct in6_addr a;

	take_string(ld, v, "http_trust_proxy", &c->http_trust_proxy, false);
	if (c->http_trust_proxy && inet_pton(AF_INET, c->http_trust_proxy, &a) != 1 &&
	    inet_pton(AF_INET6, c->http_trust_proxy, &a) != 1)
		complain(ld, "http_trust_proxy", "must be the proxy's IP address, such as "
			 "\"127.0.0.1\"");
}

static void take_member(struct loader *ld, struct settings *c,
			const char *key, json_t *v)
{
	if (!strcmp(key, "socket"))
		take_string(ld, v, key, &c->socket_path, true);
	else if (!strcmp(key, "socket_group"))
		take_string(ld, v, key, &c->socket_group, false);
	else if (!strcmp(key, "socket_mode"))
		take_mode(ld, v, &c->socket_mode);
	else if (!strcmp(key, "operator_group"))
		take_string(ld, v, key, &c->operator_group, false);
	else if (!strcmp(key, "tcp_listen"))
		take_listen(ld, v, key, &c->tcp_listen, &c->tcp_host, &c->tcp_port);
	else if (!strcmp(key, "http_listen"))
		take_listen(ld, v, key, &c->http_listen, &c->http_host, &c->http_port);
	else if (!strcmp(key, "http_root"))
		take_string(ld, v, key, &c->http_root, true);
	else if (!strcmp(key, "http_allowed_hosts"))
		take_allowed_hosts(ld, v, c);
	else if (!strcmp(key, "http_trust_proxy"))
		take_proxy(ld, v, c);
	else if (!strcmp(key, "token_file"))
		take_string(ld, v, key, &c->token_file, true);
	else if (!strcmp(key, "state_dir"))
		take_string(ld, v, key, &c->state_dir, true);
	else if (!strcmp(key, "limits"))
		take_limits(ld, v, &c->limits);
	else if (!strcmp(key, "mqtt"))
		take_mqtt(ld, v, c);
	else if (!strcmp(key, "postgres"))
		take_postgres(ld, v, c);
	else if (!strcmp(key, "instruments")) {
		if (!json_is_array(v) || json_array_size(v) == 0) {
			complain(ld, key, "must be a non-empty array");
			return;
		}
		/* Kept as the drivers' own format for their parser. */
		free(c->instruments_json);
		json_t *wrap = json_pack("{s:O}", "instruments", v);
		c->instruments_json = wrap ? json_dumps(wrap, JSON_COMPACT) : NULL;
		json_decref(wrap);
	} else
		complain(ld, key, "unknown setting");
}

int settings_load(const char *path, struct settings **out,
		settings_error_fn report, void *data)
{
	struct loader ld = { .source = path, .report = report, .data = data };
	struct settings *c = NULL;
	_cleanup_free_ char *text = NULL;
	json_error_t je;
	json_t *root, *v;
	const char *key;
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
		json_object_foreach(root, key, v)
			take_member(&ld, c, key, v);
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
