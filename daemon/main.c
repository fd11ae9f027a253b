/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asphd: the measurement daemon. docs/asphd.8.md describes its use. */
#include <errno.h>
#include <getopt.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <gsl/gsl_errno.h>
#include <systemd/sd-daemon.h>

#include "account.h"
#include "asph/instrument.h"
#include "asphd.h"
#include "config.h"
#include "dirs.h"
#include "log.h"
#include "util-mem.h"

/* Exit codes, documented in docs/asphd.8.md. */
enum {
	ASPHD_EXIT_OK = 0,
	ASPHD_EXIT_FAILURE = 1,
	ASPHD_EXIT_USAGE = 2,
	ASPHD_EXIT_CONFIG = 3,
};

#define DEFAULT_CONFIG "/etc/asphd/asphd.conf"

void daemon_update_status(struct daemon *d)
{
	char text[128];
	size_t n = 0;

	text[0] = '\0';
	for (size_t i = 0; i < d->n_instruments && n < sizeof(text); i++) {
		struct instrument *in = &d->instruments[i];
		if (!in->job)
			continue;
		n += (size_t)snprintf(text + n, sizeof(text) - n, "%s%s job %" PRId64 ": %d %%",
				      n ? ", " : "", in->paused ? "paused" : "measuring", in->job,
				      in->total > 0 ? (int)(100 * in->done / in->total) : 0);
	}
	if (!text[0])
		snprintf(text, sizeof(text), "%s", d->shutting_down ? "stopping"
					      : d->queue_running ? "idle" : "idle, queue stopped");
	if (strcmp(text, d->status_text)) {
		snprintf(d->status_text, sizeof(d->status_text), "%s", text);
		sd_notifyf(0, "STATUS=%s", text);
	}
}

static void report_config_error(const struct asph_error *err, void *data)
{
	char buf[1024];
	int *n = data;

	fprintf(stderr, "asphd: %s\n", asph_error_format(err, buf, sizeof(buf)));
	(*n)++;
}

/* Operator group by name, looked up again on reload. */
static int resolve_groups(struct daemon *d)
{
	d->have_operator_group = false;
	if (!d->config->operator_group)
		return 0;
	int r = account_group_id(d->config->operator_group, &d->operator_gid);
	if (r < 0) {
		log_error("operator_group: group \"%s\": %s", d->config->operator_group,
			  r == -ENOENT ? "does not exist" : strerror(-r));
		return r;
	}
	d->have_operator_group = true;
	return 0;
}

static int check_config(const char *path)
{
	struct settings *cfg = NULL;
	struct asph_registry *reg = NULL;
	struct asph_config *ic = NULL;
	struct asph_error err;
	int n_errors = 0, r;

	r = settings_load(path, &cfg, report_config_error, &n_errors);
	if (r == 0) {
		asph_error_clear(&err);
		r = instruments_load(cfg, &reg, &ic, &err);
		if (r < 0)
			report_config_error(&err, &n_errors);
		gid_t gid;
		int g = 0;
		if (r == 0 && cfg->operator_group)
			g = account_group_id(cfg->operator_group, &gid);
		if (g < 0) {
			fprintf(stderr, "asphd: %s: operator_group: group \"%s\": %s\n", path,
				cfg->operator_group, g == -ENOENT ? "does not exist" : strerror(-g));
			n_errors++;
		}
	}
	if (r == 0 && n_errors == 0)
		printf("%s: OK, %zu instrument(s)\n", path ? path : "(defaults)", ic->n);
	asph_config_free(ic);
	asph_registry_free(reg);
	settings_free(cfg);
	return n_errors || r < 0 ? ASPHD_EXIT_CONFIG : ASPHD_EXIT_OK;
}

static int on_terminate(sd_event_source *s, const struct signalfd_siginfo *si, void *data)
{
	struct daemon *d = data;

	if (d->shutting_down)
		return 0;
	log_info("signal %s: stopping", strsignal((int)si->ssi_signo));
	sd_notify(0, "STOPPING=1");
	jobs_shutdown(d);
	daemon_update_status(d);
	return 0;
}

static int on_reload(sd_event_source *s, const struct signalfd_siginfo *si, void *data)
{
	struct daemon *d = data;
	struct settings *cfg = NULL;
	int n_errors = 0;

	sd_notify(0, "RELOADING=1");
	if (settings_load(d->config_path, &cfg, report_config_error, &n_errors) < 0) {
		log_error("reload: the configuration has %d error(s); keeping the old one", n_errors);
		sd_notify(0, "READY=1");
		return 0;
	}
	if ((cfg->instruments_json || d->config->instruments_json) &&
	    (!cfg->instruments_json || !d->config->instruments_json ||
	     strcmp(cfg->instruments_json, d->config->instruments_json)))
		log_warning("reload: instrument changes take effect at the next start");
	/* What a running daemon can change: limits, groups, the mode of
	 * new sockets. Listener and state paths stay. */
	/* d->socket_path and d->state_dir point at these strings: move them. */
	free(cfg->socket_path);
	cfg->socket_path = d->config->socket_path;
	d->config->socket_path = NULL;
	free(cfg->state_dir);
	cfg->state_dir = d->config->state_dir;
	d->config->state_dir = NULL;
	free(cfg->instruments_json);
	cfg->instruments_json = d->config->instruments_json;
	d->config->instruments_json = NULL;
	settings_free(d->config);
	d->config = cfg;
	resolve_groups(d);
	log_info("configuration reloaded");
	sd_notify(0, "READY=1");
	return 0;
}

static int setup(struct daemon *d)
{
	_cleanup_free_ char *db = NULL;
	struct asph_error err;
	char buf[1024];
	const char *env;
	int r;

	asph_error_clear(&err);
	if (d->socket_override) {
		free(d->config->socket_path);
		d->config->socket_path = strdup(d->socket_override);
	}
	if (d->state_override) {
		free(d->config->state_dir);
		d->config->state_dir = strdup(d->state_override);
	} else if (!d->config->source || !strcmp(d->config->state_dir, "/var/lib/asphd")) {
		/* systemd's StateDirectory= tells where ours is. */
		env = getenv("STATE_DIRECTORY");
		if (env && env[0] == '/' && !strchr(env, ':')) {
			free(d->config->state_dir);
			d->config->state_dir = strdup(env);
		}
	}
	if (!d->config->socket_path || !d->config->state_dir)
		return -ENOMEM;
	d->state_dir = d->config->state_dir;
	d->socket_path = d->config->socket_path;
	r = dirs_make_state(d->state_dir);
	if (r < 0)
		return r;
	if (asprintf(&db, "%s/jobs.sqlite", d->state_dir) < 0)
		return -ENOMEM;
	r = store_open(db, &d->store, &err);
	if (r == 0)
		r = jobs_init(d);
	if (r < 0) {
		log_error("%s", err.message[0] ? asph_error_format(&err, buf, sizeof(buf))
					       : strerror(-r));
		return r;
	}
	r = instruments_load(d->config, &d->registry, &d->instrument_config, &err);
	if (r == 0)
		r = instruments_setup(d, &err);
	if (r < 0) {
		log_error("instruments: %s", asph_error_format(&err, buf, sizeof(buf)));
		return r;
	}
	if (resolve_groups(d) < 0)
		return -ENOENT;
	return server_listen(d);
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
	r = setup(d);
	if (r < 0)
		return r;
	log_info("listening on %s, state in %s, %zu instrument(s), queue %s", d->socket_path,
		 d->state_dir, d->n_instruments, d->queue_running ? "running" : "stopped");
	daemon_update_status(d);
	sd_notify(0, "READY=1");
	jobs_schedule(d);
	return sd_event_loop(d->event);
}

static void teardown(struct daemon *d)
{
	server_close(d);
	instruments_free(d);
	asph_config_free(d->instrument_config);
	asph_registry_free(d->registry);
	store_close(d->store);
	settings_free(d->config);
	sd_event_unref(d->event);
}

static void usage(FILE *f)
{
	fprintf(f, "Usage: asphd [OPTIONS]\n\n"
		   "The asphd measurement daemon.\n\n"
		   "  -c, --config FILE     configuration (default %s if it exists)\n"
		   "  -s, --socket PATH     unix socket (default %s)\n"
		   "  -d, --state-dir DIR   jobs, scans and results (default /var/lib/asphd)\n"
		   "      --check-config    check the configuration, name every error, exit\n"
		   "  -v, --verbose         log debug messages\n"
		   "      --version         print the version\n"
		   "  -h, --help            this help\n", DEFAULT_CONFIG, PROTO_DEFAULT_SOCKET);
}

int main(int argc, char **argv)
{
	static const struct option opts[] = {
		{ "config", required_argument, NULL, 'c' },
		{ "socket", required_argument, NULL, 's' },
		{ "state-dir", required_argument, NULL, 'd' },
		{ "check-config", no_argument, NULL, 'C' },
		{ "verbose", no_argument, NULL, 'v' },
		{ "version", no_argument, NULL, 'V' },
		{ "help", no_argument, NULL, 'h' },
		{ NULL, 0, NULL, 0 },
	};
	struct daemon d = { .unix_fd = -1, .tcp_fd = -1 };
	bool check = false, verbose = false;
	int c, r, n_errors = 0;

	gsl_set_error_handler_off();
	while ((c = getopt_long(argc, argv, "c:s:d:vh", opts, NULL)) != -1) {
		switch (c) {
		case 'c': d.config_path = optarg; break;
		case 's': d.socket_override = optarg; break;
		case 'd': d.state_override = optarg; break;
		case 'C': check = true; break;
		case 'v': verbose = true; break;
		case 'V': printf("asphd %s\n", ASPH_VERSION); return ASPHD_EXIT_OK;
		case 'h': usage(stdout); return ASPHD_EXIT_OK;
		default: usage(stderr); return ASPHD_EXIT_USAGE;
		}
	}
	if (optind < argc) {
		fprintf(stderr, "asphd: unexpected argument '%s'\n", argv[optind]);
		return ASPHD_EXIT_USAGE;
	}
	if (!d.config_path && access(DEFAULT_CONFIG, F_OK) == 0)
		d.config_path = DEFAULT_CONFIG;
	if (check)
		return check_config(d.config_path);
	log_setup(verbose ? LOG_DEBUG : LOG_INFO);
	if (settings_load(d.config_path, &d.config, report_config_error, &n_errors) < 0)
		return ASPHD_EXIT_CONFIG;
	r = run(&d);
	if (r < 0) {
		log_error("cannot run: %s", strerror(-r));
		sd_notifyf(0, "ERRNO=%d", -r);
	}
	teardown(&d);
	return r < 0 ? ASPHD_EXIT_FAILURE : d.exit_code;
}
