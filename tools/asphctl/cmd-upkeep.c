/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The administrator's commands (docs/admin.md): backup and health. */
#include <errno.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "asphctl.h"
#include "progress.h"
#include "util-mem.h"
#include "util-time.h"

/* How often backup.get is asked while the copy is made: soon at first (a
 * small store is copied at once), then at most every half second. */
#define POLL_FIRST_MS 20
#define POLL_MAX_MS 500
/* The health's default wait for the daemon's answer. */
#define HEALTH_TIMEOUT_S 10

/* ---------------------------------------------------------------- backup */

/* Waits for this connection's copy to be made, its pages on a terminal
 * unless quiet: 0 with *info (the last backup.get), or the exit code. */
static int wait_copy(struct ctl *ctl, bool quiet, json_t **info)
{
	unsigned wait_ms = POLL_FIRST_MS;
	struct progress p;
	int code;

	progress_start(&p, "copying the job store", "pages", quiet || ctl->json);
	for (;;) {
		const char *state;

		code = ctl_call(ctl, "backup.get", NULL, info);
		if (code)
			break;
		state = json_string_value(json_object_get(*info, "state"));
		if (state && strcmp(state, "copying"))
			break;
		progress_show(&p, (size_t)json_integer_value(json_object_get(*info, "pages_done")),
			      (size_t)json_integer_value(json_object_get(*info, "pages_total")));
		json_decref(*info);
		*info = NULL;
		msleep(wait_ms);
		wait_ms = wait_ms * 2 > POLL_MAX_MS ? POLL_MAX_MS : wait_ms * 2;
	}
	progress_stop(&p);
	return code;
}

int cmd_backup(struct ctl *ctl, int argc, char **argv)
{
	static const char usage[] = "backup FILE [--quiet] [--json]";
	_cleanup_(json_decrefp) json_t *started = NULL, *info = NULL, *params = NULL;
	const char *file, *name, *sha;
	bool quiet = false;
	json_int_t size;
	int code;

	if ((code = ctl_flag_option(ctl, argc, argv, "quiet", 'q', &quiet, usage)) >= 0)
		return code;
	if (optind + 1 != argc)
		return ctl_usage_error(usage);
	file = argv[optind];
	code = ctl_call(ctl, "backup.start", NULL, &started);
	if (!code)
		code = wait_copy(ctl, quiet, &info);
	if (code)
		return code;
	name = json_string_value(json_object_get(info, "name"));
	if (!name || strcmp(json_string_value(json_object_get(info, "state")), "done")) {
		fprintf(stderr, "asphctl: the daemon could not copy its job store: %s\n",
			json_string_value(json_object_get(info, "error")));
		return EXIT_FAILURE_RUN;
	}
	params = json_object();
	/* The copy's file only: mode 0600, it holds every job and the tokens'
	 * digests. */
	code = params ? ctl_fetch_file(ctl, "backup.file", params, name, file, 0600,
				       quiet || ctl->json)
		      : EXIT_FAILURE_RUN;
	if (code)
		return code;
	size = json_integer_value(json_object_get(info, "size"));
	sha = json_string_value(json_object_get(info, "sha256"));
	if (ctl->json) {
		json_object_set_new(info, "file", json_string(file));
		ctl_print_json(info);
	} else {
		printf("%s: the job store as of %s, %lld bytes, sha256 %s\n", file,
		       json_string_value(json_object_get(info, "started")), (long long)size,
		       sha ? sha : "?");
	}
	return EXIT_OK;
}

/* ---------------------------------------------------------------- health */

static int health_down(struct ctl *ctl, const struct ctl_error *e)
{
	char detail[700];

	if (e->detail[0])
		snprintf(detail, sizeof(detail), "%s: %s", e->message, e->detail);
	else
		snprintf(detail, sizeof(detail), "%s", e->message);
	if (ctl->json) {
		_cleanup_(json_decrefp) json_t *j = json_pack("{s:s, s:s}", "status", "down",
							       "detail", detail);
		ctl_print_json(j);
	} else {
		_cleanup_free_ char *text = ctl_escape(detail, false);
		printf("down: %s\n", text ? text : "?");
	}
	return EXIT_UNREACHABLE;
}

int cmd_health(struct ctl *ctl, int argc, char **argv)
{
	static const char usage[] = "health [--timeout SECONDS] [--json]";
	static const struct option opts[] = {
		{ "timeout", required_argument, NULL, 't' },
		CTL_JSON_OPTION, CTL_HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	_cleanup_(json_decrefp) json_t *health = NULL;
	struct ctl_error e = { 0 };
	struct conn *conn = NULL;
	long long timeout_s = HEALTH_TIMEOUT_S;
	const char *status;
	size_t i;
	json_t *v;
	int c;

	while ((c = ctl_option(ctl, argc, argv, "", opts, usage)) > 0)
		if (c == 't' && ctl_parse_integer(optarg, 1, 3600, &timeout_s) < 0) {
			fprintf(stderr, "asphctl: --timeout takes seconds from 1 to 3600, not '%s'\n",
				optarg);
			return EXIT_USAGE;
		}
	if ((c = ctl_options_exit(c)) >= 0)
		return c;
	if (optind != argc)
		return ctl_usage_error(usage);
	if (conn_open_within(ctl->socket, (int)timeout_s * 1000, &conn, &e) < 0 ||
	    conn_call(conn, "daemon.health", NULL, &health, &e) < 0) {
		conn_close(conn);
		return health_down(ctl, &e);
	}
	conn_close(conn);
	status = json_string_value(json_object_get(health, "status"));
	if (ctl->json) {
		ctl_print_json(health);
	} else {
		ctl_escape_json(health);
		printf("%s\n", status ? status : "?");
		json_array_foreach(json_object_get(health, "reasons"), i, v)
			printf("  %s: %s\n", json_string_value(json_object_get(v, "check")),
			       json_string_value(json_object_get(v, "detail")));
	}
	return status && !strcmp(status, "ok") ? EXIT_OK : EXIT_DEGRADED;
}
