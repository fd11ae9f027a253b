/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * asphd: the measurement daemon (docs/asphd.8.md describes its use). This
 * file is the process: options, the configuration, signals, the event
 * loop, and the wiring of the modules, which it alone knows all of
 * (docs/architecture.md). Event loop thread.
 */
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <malloc.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <gsl/gsl_errno.h>
#include <systemd/sd-daemon.h>

#include "access.h"
#include "asph-proto.h"
#include "backup.h"
#include "config.h"
#include "devices.h"
#include "dirs.h"
#include "events.h"
#include "fleetdb.h"
#include "instruments.h"
#include "jobs.h"
#include "log.h"
#include "monitor.h"
#include "mqtt.h"
#include "outbox.h"
#include "rpc.h"
#include "server.h"
#include "web.h"
#include "settings.h"
#include "tasks.h"
#include "telemetry.h"
#include "tokens.h"
#include "turns.h"
#include "util-time.h"
#include "util-mem.h"
#include "util-suggest.h"

/* Exit codes, documented in docs/asphd.8.md. */
enum {
	ASPHD_EXIT_OK = 0,
	ASPHD_EXIT_FAILURE = 1,
	ASPHD_EXIT_USAGE = 2,
	ASPHD_EXIT_CONFIG = 3,
};

#define DEFAULT_CONFIG "/etc/asphd/asphd.conf"
/* The threads that check and estimate plans and read scans for the web
 * page (tasks.h), and of them those kept for operators' tasks: a reader's
 * estimates cannot hold up an operator's submission. */
#define TASK_THREADS 2
#define TASK_THREADS_RESERVED 1

struct daemon {
	const char *config_path;
	const char *socket_override;
	const char *state_override;

	/* What the configuration gives, checked (load_configuration()). */
	struct settings *settings;
	struct settings_limits limits;  /* the modules read these; a reload writes them */
	struct settings_health health;  /* monitor.c reads these; so does a reload */
	struct instruments *instruments;
	struct access *access;
	struct addrinfo *tcp;           /* tcp_listen's addresses */
	struct addrinfo *http;          /* http_listen's addresses */
	struct mqtt_credentials mqtt_credentials;
	char *pg_password;              /* postgres.password_file's */

	sd_event *event;
	uint64_t started_usec;
	struct events *events;
	struct jobs *jobs;
	struct rpc *rpc;
	struct turns *turns;            /* the clients' work, every listener's */
	struct tasks *tasks;            /* plans checked and estimated, scans read */
	struct server *server;
	struct web *web;                /* NULL without http_listen */
	struct tokens *tokens;
	struct backups *backups;        /* copies of the job store for clients */
	struct monitor *monitor;        /* health and metrics */
	/* What leaves the PC (docs/fleet.md): NULL without mqtt/postgres. */
	char host[256];
	struct outbox *outbox;
	struct telemetry *telemetry;
	struct mqtt *mqtt;
	struct fleetdb *fleetdb;
	bool mqtt_up, fleetdb_up;
	char fleetdb_down[256];         /* why, as last logged */
	int watch_outbox, watch_telemetry;
	sd_event_source *revalidate;    /* ends the sessions of revoked or expired tokens */
	sd_event_source *token_expiry;  /* the next expiry of a token */
	char status[128];               /* as systemd was last told */
	bool stopping;
	int exit_code;
};

static void report_config_error(const struct asph_error *err, void *data)
{
	char buf[1024];
	int *n = data;

	fprintf(stderr, "asphd: %s\n", asph_error_format(err, buf, sizeof(buf)));
	(*n)++;
}

/* --------------------------------------------------------- configuration */

/* The addresses of a listen setting (field: tcp_listen, http_listen). */
static int resolve_listen(const struct settings *s, const char *field, const char *host,
			  const char *port, struct addrinfo **out, settings_error_fn report,
			  void *data)
{
	struct asph_error err;
	int r;

	if (!host)
		return 0;
	asph_error_clear(&err);
	r = server_resolve_tcp(host, port, out, &err);
	if (r < 0) {
		settings_locate(s, field, &err);
		report(&err, data);
	}
	return r;
}

/* http_root, when the web page is on: a folder the daemon can open, that
 * only root and the daemon's user may write, nor any file in it (the page
 * compiled in is served without it). */
static void check_http_root(const struct settings *s, settings_error_fn report, void *data)
{
	struct asph_error err;
	int fd, r;

	if (!s->http_listen || !s->http_root)
		return;
	asph_error_clear(&err);
	fd = open(s->http_root, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
	if (fd >= 0) {
		close(fd);
		if (dirs_check_page(s->http_root, &err) == 0)
			return;
	} else {
		r = -errno;
		asph_error_set(&err, r, "%s: %s (set http_root to the folder of the page's files, "
			       "or remove it to serve the built-in page)", s->http_root, strerror(-r));
	}
	settings_locate(s, "http_root", &err);
	report(&err, data);
}

/*
 * Everything the configuration says that needs more than the file to
 * check: the instruments against the drivers, the operator group, the
 * token file, the TCP address, the web page's folder. `asphd
 * --check-config` and the start run this same function, so that they
 * agree. Returns the number of errors
 * (reported as found).
 */
static int load_configuration(struct daemon *d)
{
	struct asph_error err;
	int n_errors = 0;

	asph_error_clear(&err);
	if (instruments_load(d->settings, &d->instruments, &err) < 0)
		report_config_error(&err, &n_errors);
	access_load(d->settings, &d->access, report_config_error, &n_errors);
	resolve_listen(d->settings, "tcp_listen", d->settings->tcp_host, d->settings->tcp_port,
		       &d->tcp, report_config_error, &n_errors);
	resolve_listen(d->settings, "http_listen", d->settings->http_host,
		       d->settings->http_port, &d->http, report_config_error, &n_errors);
	check_http_root(d->settings, report_config_error, &n_errors);
	mqtt_credentials_load(d->settings, &d->mqtt_credentials, report_config_error, &n_errors);
	fleetdb_password_load(d->settings, &d->pg_password, report_config_error, &n_errors);
	return n_errors;
}

static void unload_configuration(struct daemon *d)
{
	if (d->tcp)
		freeaddrinfo(d->tcp);
	d->tcp = NULL;
	if (d->http)
		freeaddrinfo(d->http);
	d->http = NULL;
	access_free(d->access);
	d->access = NULL;
	mqtt_credentials_clear(&d->mqtt_credentials);
	if (d->pg_password)
		explicit_bzero(d->pg_password, strlen(d->pg_password));
	free(d->pg_password);
	d->pg_password = NULL;
	instruments_free(d->instruments);
	d->instruments = NULL;
	settings_free(d->settings);
	d->settings = NULL;
}

/* --device-policy: the drop-in or the rules the instruments need. */
static int device_policy(struct daemon *d, const char *kind)
{
	int n_errors = 0, r;

	if (strcmp(kind, "systemd") && strcmp(kind, "udev")) {
		fprintf(stderr, "asphd: --device-policy takes systemd or udev, not \"%s\"\n", kind);
		return ASPHD_EXIT_USAGE;
	}
	if (settings_load(d->config_path, &d->settings, report_config_error, &n_errors) < 0)
		return ASPHD_EXIT_CONFIG;
	n_errors = load_configuration(d);
	r = n_errors ? -EINVAL : devices_policy(d->instruments, kind, stdout);
	unload_configuration(d);
	return r < 0 ? ASPHD_EXIT_CONFIG : ASPHD_EXIT_OK;
}

/* --list-settings: every setting of the file, a line each: name, what it
 * takes, its default and what it does, separated by tabs. */
static int list_settings(void)
{
	for (size_t i = 0; i < settings_count(); i++) {
		struct setting_info info;
		settings_describe(i, &info);
		printf("%s\t%s\t%s\t%s\n", info.name, info.type, info.fallback, info.help);
	}
	return ASPHD_EXIT_OK;
}

/* --list-methods: every method of the protocol, a line each: its name and
 * the role it needs, separated by a tab. */
static int list_methods(void)
{
	enum access_role need;
	const char *name;

	for (size_t i = 0; (name = rpc_method(i, &need)); i++)
		printf("%s\t%s\n", name, access_role_name(need));
	return ASPHD_EXIT_OK;
}

static int check_config(struct daemon *d)
{
	int n_errors = 0;

	if (settings_load(d->config_path, &d->settings, report_config_error, &n_errors) < 0)
		return ASPHD_EXIT_CONFIG;
	n_errors = load_configuration(d);
	if (n_errors == 0)
		printf("%s: OK, %zu instrument(s)\n", d->config_path ? d->config_path : "(defaults)",
		       instruments_count(d->instruments));
	unload_configuration(d);
	return n_errors ? ASPHD_EXIT_CONFIG : ASPHD_EXIT_OK;
}

/* The command line's socket and state directory, else systemd's, in s. */
static int apply_overrides(const struct daemon *d, struct settings *s)
{
	const char *env;

	if (d->socket_override) {
		free(s->socket_path);
		s->socket_path = strdup(d->socket_override);
	}
	if (d->state_override) {
		free(s->state_dir);
		s->state_dir = strdup(d->state_override);
	} else if (!s->source || !strcmp(s->state_dir, SETTINGS_STATE_DIR)) {
		/* systemd's StateDirectory= tells where ours is. */
		env = getenv("STATE_DIRECTORY");
		if (env && env[0] == '/' && !strchr(env, ':')) {
			free(s->state_dir);
			s->state_dir = strdup(env);
		}
	}
	return s->socket_path && s->state_dir ? 0 : -ENOMEM;
}

/*
 * The descriptors the clients need besides the daemon's own: max_clients
 * and root's own on the socket, and with http_listen as many web
 * connections again and those making room. The soft limit is raised as
 * far as the hard one (LimitNOFILE=) allows. 0, or -EMFILE when it cannot
 * be, which report says naming the setting.
 */
static int check_descriptors(const struct settings *s, size_t n_instruments,
			     settings_error_fn report, void *data)
{
	rlim_t clients = (rlim_t)s->limits.max_clients + SERVER_ROOT_CLIENTS;
	rlim_t web = s->http_listen ? (rlim_t)s->limits.max_clients + WEB_DISPLACED_MAX : 0;
	rlim_t need = clients + web + SERVER_FIXED_FDS + 4 * n_instruments;
	struct asph_error err;
	struct rlimit rl;

	if (getrlimit(RLIMIT_NOFILE, &rl) < 0 || rl.rlim_cur >= need)
		return 0;
	if (rl.rlim_max >= need) {
		rl.rlim_cur = need;
		if (setrlimit(RLIMIT_NOFILE, &rl) == 0)
			return 0;
	}
	asph_error_clear(&err);
	asph_error_set(&err, -EMFILE, "%u clients%s need about %llu file descriptors, and this "
		       "process may open %llu (LimitNOFILE=, ulimit -n): lower "
		       "limits.max_clients or raise the limit", s->limits.max_clients,
		       web ? " on the socket and as many on the web listener" : "",
		       (unsigned long long)need, (unsigned long long)rl.rlim_max);
	settings_locate(s, "limits.max_clients", &err);
	report(&err, data);
	return -EMFILE;
}

/* ------------------------------------------------------------ status */

/* systemd's STATUS= line, told when it changes. */
static void update_status(struct daemon *d)
{
	char text[128];

	jobs_status_text(d->jobs, text, sizeof(text));
	if (strcmp(text, d->status)) {
		snprintf(d->status, sizeof(d->status), "%s", text);
		sd_notifyf(0, "STATUS=%s", text);
	}
}

/* The event watch behind the status line: every event may change it. */
static void status_watch(const struct event *ev, void *data)
{
	update_status(data);
}

/* ------------------------------------------------------------ signals */

static void jobs_stopped(void *data)
{
	struct daemon *d = data;

	sd_event_exit(d->event, d->exit_code);
}

static int on_terminate(sd_event_source *s, const struct signalfd_siginfo *si, void *data)
{
	struct daemon *d = data;

	if (d->stopping)
		return 0;
	d->stopping = true;
	log_info("signal %s: stopping", strsignal((int)si->ssi_signo));
	sd_notify(0, "STOPPING=1");
	server_refuse_clients(d->server);
	jobs_shutdown(d->jobs, jobs_stopped, d);
	update_status(d);
	return 0;
}

/* Whether two optional strings differ. */
static bool differ(const char *a, const char *b)
{
	return (a || b) && (!a || !b || strcmp(a, b));
}

static void append(char *buf, size_t size, const char *what)
{
	size_t n = strlen(buf);

	snprintf(buf + n, size - n, "%s%s", n ? ", " : "", what);
}

/* A section of the configuration as the file has it (JSON text, static;
 * NULL when absent), to tell whether a reload changes it. */
static const char *section_text(const struct settings *s, const char *name)
{
	static char buf[2][4096];
	static int k;
	json_t *root = s->text ? json_loadb(s->text, s->text_len, 0, NULL) : NULL;
	json_t *v = json_object_get(root, name);
	char *t = v ? json_dumps(v, JSON_COMPACT | JSON_SORT_KEYS) : NULL;
	const char *out = NULL;

	if (t) {
		k ^= 1;
		snprintf(buf[k], sizeof(buf[k]), "%s", t);
		out = buf[k];
	}
	free(t);
	json_decref(root);
	return out;
}

/* What next changes that only a restart applies: named into why (empty
 * when nothing). */
static void needs_restart(const struct daemon *d, const struct settings *next, char *why,
			  size_t size)
{
	const struct settings *now = d->settings;
	char tcp[256];

	why[0] = '\0';
	if (differ(next->socket_path, now->socket_path))
		append(why, size, "socket");
	if (differ(next->state_dir, now->state_dir))
		append(why, size, "state_dir");
	if (differ(next->instruments_json, now->instruments_json))
		append(why, size, "instruments");
	if (differ(next->http_listen, now->http_listen))
		append(why, size, "http_listen");
	if (differ(next->http_root, now->http_root))
		append(why, size, "http_root");
	if (differ(section_text(next, "http_allowed_hosts"), section_text(now, "http_allowed_hosts")))
		append(why, size, "http_allowed_hosts");
	if (differ(next->http_trust_proxy, now->http_trust_proxy))
		append(why, size, "http_trust_proxy");
	if (differ(section_text(next, "mqtt"), section_text(now, "mqtt")))
		append(why, size, "mqtt");
	if (differ(section_text(next, "postgres"), section_text(now, "postgres")))
		append(why, size, "postgres");
	if (server_check_reload(d->server, next, tcp, sizeof(tcp)) < 0)
		append(why, size, tcp);
}

/*
 * Everything a running daemon can apply: the limits, who may do what (the
 * operator group, the token: a TCP client that sent a token that is no
 * longer there is disconnected), the socket's mode and group, and the end
 * of the TCP listener. A configuration with any error, or one that changes
 * what only a restart applies (the socket's path, the state directory, the
 * instruments, a new TCP address), is refused whole, saying which.
 */
static int on_reload(sd_event_source *s, const struct signalfd_siginfo *si, void *data)
{
	struct daemon *d = data;
	struct settings *next = NULL;
	struct access *access = NULL;
	char why[512];
	int n_errors = 0;

	sd_notify(0, "RELOADING=1");
	if (settings_load(d->config_path, &next, report_config_error, &n_errors) == 0 &&
	    access_load(next, &access, report_config_error, &n_errors) == 0 &&
	    apply_overrides(d, next) == 0)
		check_descriptors(next, instruments_count(d->instruments), report_config_error,
				  &n_errors);
	if (n_errors || !next || !access) {
		log_error("reload: the configuration has %d error(s); keeping the old one", n_errors);
		goto keep;
	}
	needs_restart(d, next, why, sizeof(why));
	if (why[0]) {
		log_error("reload refused: %s changed, which needs a restart (systemctl restart "
			  "asphd); the running configuration is kept", why);
		goto keep;
	}
	d->limits = next->limits;
	d->health = next->health;
	access_set_tokens(access, d->tokens);
	rpc_set_access(d->rpc, access);
	access_free(d->access);
	d->access = steal_ptr(access);
	server_reload(d->server, next);
	server_revalidate(d->server);
	if (d->web)
		web_revalidate(d->web);
	settings_free(d->settings);
	d->settings = steal_ptr(next);
	log_info("configuration reloaded");
keep:
	access_free(access);
	settings_free(next);
	sd_notify(0, "READY=1");
	return 0;
}

/* ------------------------------------------------------------ tokens */

/* After the answer that revoked a token: its sessions end, the calling
 * one included, outside of the call. */
static int on_revalidate(sd_event_source *s, void *data)
{
	struct daemon *d = data;

	server_revalidate(d->server);
	if (d->web)
		web_revalidate(d->web);
	return 0;
}

static void tokens_changed(void *data)
{
	struct daemon *d = data;

	sd_event_source_set_enabled(d->revalidate, SD_EVENT_ONESHOT);
}

static void arm_token_expiry(struct daemon *d);

static int on_token_expiry(sd_event_source *s, uint64_t usec, void *data)
{
	struct daemon *d = data;

	server_revalidate(d->server);
	if (d->web)
		web_revalidate(d->web);
	arm_token_expiry(d);
	return 0;
}

/* The timer at the next expiry of a token: its sessions end then. */
static void arm_token_expiry(struct daemon *d)
{
	int64_t now = now_realtime_ns(), next = tokens_next_expiry(d->tokens, now);

	if (!next) {
		sd_event_source_set_enabled(d->token_expiry, SD_EVENT_OFF);
		return;
	}
	sd_event_source_set_time(d->token_expiry, (uint64_t)(next / 1000) + 1);
	sd_event_source_set_enabled(d->token_expiry, SD_EVENT_ONESHOT);
}

static void tokens_changed_or_created(void *data)
{
	tokens_changed(data);
	arm_token_expiry(data);
}

/* The job store's path, for the modules that keep things in it
 * (malloc'd, or NULL). */
static char *store_path(const struct daemon *d)
{
	char *path;

	return asprintf(&path, "%s/jobs.sqlite", d->settings->state_dir) < 0 ? NULL : path;
}

static int open_tokens(struct daemon *d)
{
	_cleanup_free_ char *path = store_path(d);
	struct asph_error err;
	char buf[1024];
	int r;

	asph_error_clear(&err);
	if (!path)
		return -ENOMEM;
	r = tokens_open(path, &d->tokens, &err);
	if (r < 0) {
		log_error("%s", asph_error_format(&err, buf, sizeof(buf)));
		return r;
	}
	tokens_set_changed(d->tokens, tokens_changed_or_created, d);
	access_set_tokens(d->access, d->tokens);
	r = sd_event_add_defer(d->event, &d->revalidate, on_revalidate, d);
	if (r >= 0)
		r = sd_event_source_set_enabled(d->revalidate, SD_EVENT_OFF);
	if (r >= 0)
		r = sd_event_add_time(d->event, &d->token_expiry, CLOCK_REALTIME, UINT64_MAX, 0,
				      on_token_expiry, d);
	if (r < 0)
		return r;
	arm_token_expiry(d);
	return 0;
}

/* ------------------------------------------------------------ fleet */

static int mqtt_send(void *data, const struct store_outbox_item *it)
{
	struct daemon *d = data;

	return mqtt_publish(d->mqtt, it->topic, it->payload, it->qos, it->retain, it->id);
}

static void mqtt_acked(void *data, int64_t tag)
{
	struct daemon *d = data;

	outbox_done(d->outbox, OUTBOX_MQTT, tag);
}

static void mqtt_link(void *data, bool up, const char *why)
{
	struct daemon *d = data;

	if (up) {
		log_info("mqtt: connected to %s (%" PRId64 " message(s) waiting)",
			 d->settings->mqtt->url, outbox_waiting(d->outbox, OUTBOX_MQTT));
		telemetry_link_up(d->telemetry);
		outbox_reset(d->outbox, OUTBOX_MQTT);
		outbox_pump(d->outbox, OUTBOX_MQTT);
	} else {
		monitor_count_error(d->monitor, MONITOR_MQTT_CONNECTION);
		log_warning("mqtt: %s %s: %s; trying again (the job states and results wait in "
			    "the outbox)", d->mqtt_up ? "lost the connection to" : "cannot connect to",
			    d->settings->mqtt->url, why);
	}
	d->mqtt_up = up;
	monitor_sink_link(d->monitor, OUTBOX_MQTT, up);
}

static int fleetdb_send_item(void *data, const struct store_outbox_item *it)
{
	struct daemon *d = data;

	return fleetdb_send(d->fleetdb, it->id, it->payload);
}

static void fleetdb_acked(void *data, int64_t id)
{
	struct daemon *d = data;

	outbox_done(d->outbox, OUTBOX_POSTGRES, id);
}

static void fleetdb_refused(void *data, int64_t id, const char *why)
{
	struct daemon *d = data;

	monitor_count_error(d->monitor, MONITOR_POSTGRES_REFUSED);
	outbox_hold(d->outbox, OUTBOX_POSTGRES, id, why);
}

static void fleetdb_link(void *data, bool up, const char *why)
{
	struct daemon *d = data;

	if (up && !d->fleetdb_up)
		log_info("postgres: connected (%" PRId64 " row(s) waiting)",
			 outbox_waiting(d->outbox, OUTBOX_POSTGRES));
	if (!up && (d->fleetdb_up || strcmp(why, d->fleetdb_down)))
		log_warning("postgres: %s; trying again (the rows wait in the outbox)", why);
	if (!up)
		snprintf(d->fleetdb_down, sizeof(d->fleetdb_down), "%s", why);
	if (!up)
		monitor_count_error(d->monitor, MONITOR_POSTGRES_CONNECTION);
	d->fleetdb_up = up;
	monitor_sink_link(d->monitor, OUTBOX_POSTGRES, up);
}

/* Every job change: its messages into the outbox. */
static void outbox_watch(const struct event *ev, void *data)
{
	struct daemon *d = data;

	if (!strcmp(ev->method, "job.state"))
		outbox_catch_up(d->outbox);
}

static int start_mqtt(struct daemon *d, char **prefix)
{
	const struct settings_mqtt *cfg = d->settings->mqtt;
	_cleanup_free_ char *client_id = NULL, *will = NULL;
	struct asph_error err;
	char buf[1024];
	int r;

	asph_error_clear(&err);
	r = telemetry_new(&(struct telemetry_setup){
			.prefix = *prefix, .daemon_id = outbox_daemon_id(d->outbox), .host = d->host,
			.qos = cfg->qos, .started_ns = now_realtime_ns(), .jobs = d->jobs,
			.instruments = d->instruments,
		}, &d->telemetry);
	if (r < 0)
		return r;
	if (cfg->client_id)
		client_id = strdup(cfg->client_id);
	else if (asprintf(&client_id, "asphd-%.64s-%.8s", d->host, outbox_daemon_id(d->outbox)) < 0)
		client_id = NULL;
	will = telemetry_offline(d->telemetry);
	if (!client_id || !will)
		return -ENOMEM;
	r = mqtt_new(&(struct mqtt_setup){
			.event = d->event, .cfg = cfg, .credentials = &d->mqtt_credentials,
			.client_id = client_id, .will_topic = telemetry_status_topic(d->telemetry),
			.will_payload = will, .acked = mqtt_acked, .link = mqtt_link, .data = d,
		}, &d->mqtt, &err);
	if (r < 0) {
		log_error("%s", asph_error_format(&err, buf, sizeof(buf)));
		return r;
	}
	telemetry_set_mqtt(d->telemetry, d->mqtt);
	outbox_set_sink(d->outbox, OUTBOX_MQTT, &(struct outbox_sink){
				.send = mqtt_send, .data = d, .window = 32 });
	d->watch_telemetry = events_watch_add(d->events, EVENT_ALL, telemetry_watch, d->telemetry,
					      NULL);
	log_info("mqtt: publishing to %s under %s as %s", cfg->url, *prefix, client_id);
	return d->watch_telemetry < 0 ? d->watch_telemetry : 0;
}

static int start_fleetdb(struct daemon *d)
{
	struct asph_error err;
	char buf[1024];
	int r;

	asph_error_clear(&err);
	r = fleetdb_new(&(struct fleetdb_setup){
			.event = d->event, .cfg = d->settings->postgres, .password = d->pg_password,
			.acked = fleetdb_acked, .link = fleetdb_link,
			.refused = fleetdb_refused, .data = d,
		}, &d->fleetdb, &err);
	if (r < 0) {
		log_error("%s", asph_error_format(&err, buf, sizeof(buf)));
		return r;
	}
	outbox_set_sink(d->outbox, OUTBOX_POSTGRES, &(struct outbox_sink){
				.send = fleetdb_send_item, .data = d, .window = 64 });
	return 0;
}

/* The outbox and its sinks, with a mqtt or a postgres section. */
static int start_fleet(struct daemon *d)
{
	const struct settings *s = d->settings;
	_cleanup_free_ char *path = NULL, *prefix = NULL;
	struct asph_error err;
	char buf[1024];
	int r;

	if (!s->mqtt && !s->postgres)
		return 0;
	if (gethostname(d->host, sizeof(d->host) - 1) < 0)
		snprintf(d->host, sizeof(d->host), "localhost");
	if (s->mqtt) {
		if (s->mqtt->prefix)
			prefix = strdup(s->mqtt->prefix);
		else if (asprintf(&prefix, "asphd/%s", d->host) < 0)
			prefix = NULL;
		if (!prefix)
			return -ENOMEM;
	}
	path = store_path(d);
	if (!path)
		return -ENOMEM;
	asph_error_clear(&err);
	r = outbox_new(&(struct outbox_setup){
			.store_path = path, .host = d->host, .mqtt_prefix = prefix,
			.mqtt_qos = s->mqtt ? s->mqtt->qos : 1, .postgres = s->postgres != NULL,
		}, &d->outbox, &err);
	if (r < 0) {
		log_error("%s", asph_error_format(&err, buf, sizeof(buf)));
		return r;
	}
	monitor_set_outbox(d->monitor, d->outbox);
	if (s->mqtt)
		monitor_add_sink(d->monitor, OUTBOX_MQTT);
	if (s->postgres)
		monitor_add_sink(d->monitor, OUTBOX_POSTGRES);
	if (s->mqtt && (r = start_mqtt(d, &prefix)) < 0)
		return r;
	if (s->postgres && (r = start_fleetdb(d)) < 0)
		return r;
	d->watch_outbox = events_watch_add(d->events, EVENT_JOB, outbox_watch, d, NULL);
	if (d->watch_outbox < 0)
		return d->watch_outbox;
	/* What changed while the daemon was not running (the jobs it found
	 * interrupted), or before a crash, is taken now. */
	outbox_catch_up(d->outbox);
	return 0;
}

static void stop_fleet(struct daemon *d)
{
	_cleanup_free_ char *goodbye = d->telemetry ? telemetry_offline(d->telemetry) : NULL;

	if (d->watch_telemetry > 0)
		events_watch_remove(d->events, d->watch_telemetry);
	if (d->watch_outbox > 0)
		events_watch_remove(d->events, d->watch_outbox);
	d->watch_telemetry = d->watch_outbox = 0;
	mqtt_free(d->mqtt, goodbye);
	d->mqtt = NULL;
	fleetdb_free(d->fleetdb);
	d->fleetdb = NULL;
	telemetry_free(d->telemetry);
	d->telemetry = NULL;
	if (d->monitor)
		monitor_set_outbox(d->monitor, NULL);
	outbox_free(d->outbox);
	d->outbox = NULL;
}

/* asphd --db-migrate: the central database's schema, made or migrated. */
static int db_migrate(struct daemon *d)
{
	struct asph_error err;
	char buf[1024];
	int n_errors = 0, r;

	if (settings_load(d->config_path, &d->settings, report_config_error, &n_errors) < 0)
		return ASPHD_EXIT_CONFIG;
	if (!d->settings->postgres) {
		fprintf(stderr, "asphd: %s has no \"postgres\" section: nothing to migrate\n",
			d->config_path ? d->config_path : "the configuration");
		unload_configuration(d);
		return ASPHD_EXIT_CONFIG;
	}
	if (fleetdb_password_load(d->settings, &d->pg_password, report_config_error,
				  &n_errors) < 0) {
		unload_configuration(d);
		return ASPHD_EXIT_CONFIG;
	}
	asph_error_clear(&err);
	r = fleetdb_migrate(d->settings->postgres, d->pg_password, stdout, &err);
	if (r < 0)
		fprintf(stderr, "asphd: %s\n", asph_error_format(&err, buf, sizeof(buf)));
	unload_configuration(d);
	return r < 0 ? ASPHD_EXIT_FAILURE : ASPHD_EXIT_OK;
}

/* ------------------------------------------------------------ running */

static int start_backups(struct daemon *d)
{
	_cleanup_free_ char *path = store_path(d);
	struct asph_error err;
	char buf[1024];
	int r;

	asph_error_clear(&err);
	if (!path)
		return -ENOMEM;
	r = backups_new(&(struct backups_setup){
			.event = d->event, .store_path = path, .limits = &d->limits,
			}, &d->backups, &err);
	if (r < 0)
		log_error("%s", asph_error_format(&err, buf, sizeof(buf)));
	return r;
}

static int start_modules(struct daemon *d)
{
	struct asph_error err;
	char buf[1024];
	int r;

	asph_error_clear(&err);
	r = events_new(&d->events);
	if (r < 0)
		return r;
	r = jobs_new(&(struct jobs_setup){
			.event = d->event, .state_dir = d->settings->state_dir,
			.instruments = d->instruments, .events = d->events, .limits = &d->limits,
		     }, &d->jobs, &err);
	if (r < 0) {
		log_error("%s", err.message[0] ? asph_error_format(&err, buf, sizeof(buf))
					       : strerror(-r));
		return r;
	}
	r = open_tokens(d);
	if (r == 0)
		r = turns_new(d->event, &d->turns);
	if (r == 0)
		r = tasks_new(&(struct tasks_setup){
				.event = d->event, .threads = TASK_THREADS,
				.reserved = TASK_THREADS_RESERVED,
			      }, &d->tasks);
	if (r < 0)
		return r;
	r = start_backups(d);
	if (r == 0)
		r = monitor_new(&(struct monitor_setup){
				.jobs = d->jobs, .instruments = d->instruments, .limits = &d->limits,
				.health = &d->health, .state_dir = d->settings->state_dir,
				.version = ASPH_VERSION, .started_ns = now_realtime_ns(),
				}, &d->monitor);
	if (r == 0)
		r = events_watch_add(d->events, EVENT_JOB, monitor_watch, d->monitor, NULL);
	if (r < 0)
		return r;
	r = rpc_new(&(struct rpc_setup){
			.event = d->event, .started_usec = d->started_usec, .jobs = d->jobs,
			.instruments = d->instruments, .events = d->events, .access = d->access,
			.tokens = d->tokens, .tasks = d->tasks, .backups = d->backups,
			.monitor = d->monitor, .limits = &d->limits,
		    }, &d->rpc);
	if (r == 0)
		r = server_new(&(struct server_setup){
				.event = d->event, .rpc = d->rpc, .turns = d->turns,
				.limits = &d->limits,
			       }, &d->server);
	if (r < 0)
		return r;
	/* The sink: events reach the clients and the status line. */
	r = events_watch_add(d->events, EVENT_ALL, server_notify, d->server, NULL);
	if (r > 0)
		r = events_watch_add(d->events, EVENT_ALL, status_watch, d, NULL);
	if (r > 0 && d->http) {
		r = web_new(&(struct web_setup){
				.event = d->event, .rpc = d->rpc, .jobs = d->jobs,
				.turns = d->turns, .tasks = d->tasks, .monitor = d->monitor,
				.limits = &d->limits, .state_dir = d->settings->state_dir,
			    }, &d->web);
		if (r == 0)
			r = events_watch_add(d->events, EVENT_ALL, web_notify, d->web, NULL);
	}
	if (r > 0)
		r = start_fleet(d);
	return r < 0 ? r : 0;
}

static int run(struct daemon *d)
{
	sigset_t mask;
	int r;

	sigemptyset(&mask);
	sigaddset(&mask, SIGTERM);
	sigaddset(&mask, SIGINT);
	sigaddset(&mask, SIGHUP);
	sigprocmask(SIG_BLOCK, &mask, NULL);
	signal(SIGPIPE, SIG_IGN);
	r = sd_event_default(&d->event);
	if (r < 0)
		return r;
	sd_event_add_signal(d->event, NULL, SIGTERM, on_terminate, d);
	sd_event_add_signal(d->event, NULL, SIGINT, on_terminate, d);
	sd_event_add_signal(d->event, NULL, SIGHUP, on_reload, d);
	/* Pings the watchdog from the loop itself: a hung loop is caught. */
	sd_event_set_watchdog(d->event, true);
	sd_event_now(d->event, CLOCK_MONOTONIC, &d->started_usec);
	r = start_modules(d);
	if (r == 0)
		r = server_listen(d->server, d->settings, d->tcp);
	if (r == 0 && d->web) {
		r = web_listen(d->web, &(struct web_listen_setup){
				.addr = d->http, .text = d->settings->http_listen,
				.host = d->settings->http_host, .root = d->settings->http_root,
				.allowed_hosts = d->settings->http_allowed_hosts,
				.trust_proxy = d->settings->http_trust_proxy,
			       });
		if (r == 0)
			log_info("web page at http://%s%s%s:%u/ (%zu address%s)",
				 strchr(d->settings->http_host, ':') ? "[" : "", d->settings->http_host,
				 strchr(d->settings->http_host, ':') ? "]" : "", web_port(d->web),
				 web_listeners(d->web), web_listeners(d->web) == 1 ? "" : "es");
	}
	if (r < 0)
		return r;
	log_info("listening on %s, state in %s, %zu instrument(s), queue %s",
		 d->settings->socket_path, d->settings->state_dir,
		 instruments_count(d->instruments),
		 jobs_queue_running(d->jobs) ? "running" : "stopped");
	update_status(d);
	sd_notify(0, "READY=1");
	jobs_schedule(d->jobs);
	return sd_event_loop(d->event);
}

static void teardown(struct daemon *d)
{
	/* The clients first: their lines cancel the tasks they wait for. */
	web_free(d->web);
	server_free(d->server);
	rpc_free(d->rpc);
	tasks_free(d->tasks);
	turns_free(d->turns);
	backups_free(d->backups);
	stop_fleet(d);
	sd_event_source_disable_unref(d->revalidate);
	sd_event_source_disable_unref(d->token_expiry);
	tokens_free(d->tokens);
	jobs_free(d->jobs);
	events_free(d->events);
	monitor_free(d->monitor);
	unload_configuration(d);
	sd_event_unref(d->event);
}

static void usage(FILE *f)
{
	fprintf(f, "Usage: asphd [OPTIONS]\n\n"
		   "The asphd measurement daemon: runs the measurement jobs that asphctl (and\n"
		   "the web page, with http_listen) submit, on the instruments of its\n"
		   "configuration. Normally started by systemd (asphd.service); the manual page\n"
		   "is asphd(8).\n\n"
		   "  -c, --config FILE     configuration (default %s if it exists)\n"
		   "  -s, --socket PATH     unix socket (default %s)\n"
		   "  -d, --state-dir DIR   jobs, scans and results (default /var/lib/asphd)\n"
		   "      --check-config    check the configuration, name every error, exit\n"
		   "      --list-settings   print every setting of the configuration file: name,\n"
		   "                        what it takes, default, meaning (tab-separated), exit\n"
		   "      --list-methods    print every method of the protocol with the role it\n"
		   "                        needs (tab-separated), exit\n"
		   "      --db-migrate      create or migrate the central database's schema\n"
		   "                        (the configuration's postgres section), exit\n"
		   "      --device-policy=systemd|udev\n"
		   "                        print the devices and hosts the instruments need,\n"
		   "                        as a systemd drop-in or as udev rules, exit\n"
		   "  -v, --verbose         log debug messages\n"
		   "      --version         print the version\n"
		   "  -h, --help            this help\n\n"
		   "Exit status: 0 stopped cleanly (or --check-config found no error), 1 could\n"
		   "not run, 2 bad command line, 3 a configuration error.\n",
		   DEFAULT_CONFIG, PROTO_DEFAULT_SOCKET);
}

int main(int argc, char **argv)
{
	static const struct option opts[] = {
		{ "config", required_argument, NULL, 'c' },
		{ "socket", required_argument, NULL, 's' },
		{ "state-dir", required_argument, NULL, 'd' },
		{ "check-config", no_argument, NULL, 'C' },
		{ "list-settings", no_argument, NULL, 'L' },
		{ "list-methods", no_argument, NULL, 'R' },
		{ "db-migrate", no_argument, NULL, 'M' },
		{ "device-policy", required_argument, NULL, 'D' },
		{ "verbose", no_argument, NULL, 'v' },
		{ "version", no_argument, NULL, 'V' },
		{ "help", no_argument, NULL, 'h' },
		{ NULL, 0, NULL, 0 },
	};
	struct daemon d = { 0 };
	const char *policy = NULL;
	bool check = false, verbose = false, migrate = false;
	int c, r, n_errors = 0;

	gsl_set_error_handler_off();
	/* A job's arrays of points (hundreds of kB to hundreds of MB) get pages
	 * of their own, returned when freed: glibc would otherwise raise this
	 * threshold after the first such free and serve the next from the
	 * heap, which keeps what the characterization has already let go of
	 * (docs/daemon.md, "Memory"). */
	mallopt(M_MMAP_THRESHOLD, 256 * 1024);
	/* Jobs, scans and results are private to the daemon's user and group,
	 * under systemd (UMask=0027) or not. */
	umask(0027);
	opterr = 0;
	while ((c = getopt_long(argc, argv, "c:s:d:vh", opts, NULL)) != -1) {
		switch (c) {
		case 'c': d.config_path = optarg; break;
		case 's': d.socket_override = optarg; break;
		case 'd': d.state_override = optarg; break;
		case 'C': check = true; break;
		case 'L': return list_settings();
		case 'R': return list_methods();
		case 'M': migrate = true; break;
		case 'D': policy = optarg; break;
		case 'v': verbose = true; break;
		case 'V': printf("asphd %s\n", ASPH_VERSION); return ASPHD_EXIT_OK;
		case 'h': usage(stdout); return ASPHD_EXIT_OK;
		default: {
			char why[256];
			fprintf(stderr, "asphd: %s\nRun 'asphd --help' for the options.\n",
				suggest_getopt_error(argv, "c:s:d:vh", opts, why, sizeof(why)));
			return ASPHD_EXIT_USAGE;
		}
		}
	}
	if (optind < argc) {
		fprintf(stderr, "asphd: unexpected argument '%s'\n", argv[optind]);
		return ASPHD_EXIT_USAGE;
	}
	if (!d.config_path && access(DEFAULT_CONFIG, F_OK) == 0)
		d.config_path = DEFAULT_CONFIG;
	if (check)
		return check_config(&d);
	if (migrate)
		return db_migrate(&d);
	if (policy)
		return device_policy(&d, policy);
	log_setup(verbose ? LOG_DEBUG : LOG_INFO);
	if (settings_load(d.config_path, &d.settings, report_config_error, &n_errors) < 0)
		return ASPHD_EXIT_CONFIG;
	if (load_configuration(&d) > 0 ||
	    check_descriptors(d.settings, instruments_count(d.instruments), report_config_error,
			      &n_errors) < 0) {
		unload_configuration(&d);
		return ASPHD_EXIT_CONFIG;
	}
	d.limits = d.settings->limits;
	d.health = d.settings->health;
	r = apply_overrides(&d, d.settings);
	if (r == 0)
		r = run(&d);
	if (r < 0) {
		log_error("cannot run: %s", strerror(-r));
		sd_notifyf(0, "ERRNO=%d", -r);
	}
	teardown(&d);
	return r < 0 ? ASPHD_EXIT_FAILURE : d.exit_code;
}
