/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asphctl.h"
#include "config.h"
#include "util-mem.h"

static const struct {
	const char *name;
	const char *summary;
	int (*run)(struct ctl *ctl, int argc, char **argv);
} commands[] = {
	{ "submit", "submit a measurement job", cmd_submit },
	{ "status", "the daemon's status, or a job's", cmd_status },
	{ "watch", "follow a job until it ends", cmd_watch },
	{ "cancel", "cancel a job", cmd_cancel },
	{ "pause", "pause a running scan", cmd_pause },
	{ "resume", "resume a paused scan, or an interrupted job", cmd_resume },
	{ "requeue", "queue a failed, interrupted or cancelled job again", cmd_requeue },
	{ "list", "list jobs", cmd_list },
	{ "result", "a job's result; --out DIR copies its files", cmd_result },
	{ "queue", "show the queue; move a job; start or stop the queue", cmd_queue },
	{ "instruments", "the instruments and their state", cmd_instruments },
	{ "drivers", "the drivers the daemon has", cmd_drivers },
	{ "lock", "lock an instrument for work at the machine", cmd_lock },
	{ "unlock", "end an instrument's lock", cmd_unlock },
	{ "token", "create, list or revoke API tokens (root)", cmd_token },
	{ "fleet", "the newest results across daemons, from the central database", cmd_fleet },
	{ "backup", "copy the daemon's job store into a file (root)", cmd_backup },
	{ "health", "ok, degraded (with the reasons) or down, for monitoring", cmd_health },
};

int ctl_fail(const struct ctl_error *e)
{
	_cleanup_free_ char *message = ctl_escape(e->message, false);
	_cleanup_free_ char *detail = ctl_escape(e->detail, false);

	if (detail && detail[0])
		fprintf(stderr, "asphctl: %s: %s\n", message ? message : "?", detail);
	else
		fprintf(stderr, "asphctl: %s\n", message ? message : "?");
	if (e->code == 0)
		return CTL_EXIT_UNREACHABLE;
	if (e->code == PROTO_PERMISSION_DENIED)
		return CTL_EXIT_DENIED;
	return CTL_EXIT_ERROR;
}

int ctl_call(struct ctl *ctl, const char *method, json_t *params, json_t **result)
{
	struct ctl_error e = { 0 };
	int r;

	if (!ctl->conn && conn_open(ctl->socket, &ctl->conn, &e) < 0) {
		json_decref(params);
		return ctl_fail(&e);
	}
	r = conn_call(ctl->conn, method, params, result, &e);
	if (r < 0)
		return ctl_fail(&e);
	if (!ctl->json)
		ctl_escape_json(*result);
	return 0;
}

void ctl_print_json(const json_t *j)
{
	_cleanup_free_ char *s = json_dumps(j, JSON_INDENT(2) | JSON_REAL_PRECISION(10));
	/* jansson escapes C0; DEL, C1 and the bidirectional controls it
	 * leaves as they are, inside strings only (JSON's syntax is ASCII). */
	_cleanup_free_ char *e = s ? ctl_escape(s, true) : NULL;

	if (e)
		puts(e);
}

int ctl_parse_integer(const char *arg, long long min, long long max, long long *v)
{
	char *end;

	errno = 0;
	*v = strtoll(arg, &end, 10);
	if (errno || end == arg || *end || *v < min || *v > max)
		return -EINVAL;
	return 0;
}

int ctl_parse_real(const char *arg, double *v)
{
	char *end;

	errno = 0;
	*v = strtod(arg, &end);
	if (errno || end == arg || *end || !isfinite(*v))
		return -EINVAL;
	return 0;
}

int64_t ctl_job_id(const char *arg)
{
	long long v;

	if (ctl_parse_integer(arg, 1, INT64_MAX, &v) < 0) {
		fprintf(stderr, "asphctl: '%s' is not a job id\n", arg);
		return -1;
	}
	return v;
}

int64_t ctl_job_operand(int argc, char **argv, const char *usage)
{
	if (optind + 1 != argc) {
		fprintf(stderr, "Usage: asphctl %s\n", usage);
		return -1;
	}
	return ctl_job_id(argv[optind]);
}

static void usage(FILE *f)
{
	fprintf(f, "Usage: asphctl [--socket PATH] [--json] COMMAND [ARGS...]\n\n"
		   "Client of the asphd measurement daemon.\n\n"
		   "  -s, --socket PATH   the daemon's socket (default $ASPHD_SOCKET or %s)\n"
		   "  -j, --json          print results as JSON\n"
		   "      --version       print the version\n\n"
		   "Commands:\n", PROTO_DEFAULT_SOCKET);
	for (size_t i = 0; i < ARRAY_SIZE(commands); i++)
		fprintf(f, "  %-12s %s\n", commands[i].name, commands[i].summary);
	fprintf(f, "\nRun 'asphctl COMMAND --help' for a command's options.\n"
		   "Exit codes: 0 ok, 1 error from the daemon, 2 usage, 3 daemon unreachable,\n"
		   "4 permission denied, 5 the job ended without a result; health: 7 down,\n"
		   "8 degraded.\n");
}

int main(int argc, char **argv)
{
	static const struct option opts[] = {
		{ "socket", required_argument, NULL, 's' },
		{ "json", no_argument, NULL, 'j' },
		{ "version", no_argument, NULL, 'V' },
		{ "help", no_argument, NULL, 'h' },
		{ NULL, 0, NULL, 0 },
	};
	struct ctl ctl = { .socket = getenv("ASPHD_SOCKET") };
	int c, r;

	if (!ctl.socket || !*ctl.socket)
		ctl.socket = PROTO_DEFAULT_SOCKET;
	/* Options before the command only; the command parses the rest. */
	while ((c = getopt_long(argc, argv, "+s:jh", opts, NULL)) != -1) {
		switch (c) {
		case 's': ctl.socket = optarg; break;
		case 'j': ctl.json = true; break;
		case 'V': printf("asphctl %s\n", ASPH_VERSION); return CTL_EXIT_OK;
		case 'h': usage(stdout); return CTL_EXIT_OK;
		default: usage(stderr); return CTL_EXIT_USAGE;
		}
	}
	if (optind >= argc) {
		usage(stderr);
		return CTL_EXIT_USAGE;
	}
	for (size_t i = 0; i < ARRAY_SIZE(commands); i++) {
		if (strcmp(argv[optind], commands[i].name))
			continue;
		char **sub = argv + optind;
		int n = argc - optind;
		optind = 0;   /* reset getopt for the command */
		r = commands[i].run(&ctl, n, sub);
		conn_close(ctl.conn);
		return r;
	}
	fprintf(stderr, "asphctl: unknown command '%s'\n", argv[optind]);
	usage(stderr);
	return CTL_EXIT_USAGE;
}
