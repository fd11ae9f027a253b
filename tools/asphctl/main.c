/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asphctl.h"
#include "command.h"
#include "config.h"
#include "util-mem.h"
#include "util-suggest.h"

static int cmd_help(struct ctl *ctl, int argc, char **argv);

/*
 * The commands: name, summary (asphctl --help), and what `asphctl help
 * COMMAND` adds to the usage line (docs/asphctl.1.md says more).
 */
static const struct ctl_command commands[] = {
	{ "submit", "submit a measurement job", cmd_submit,
	  "Queues a measurement of LENS (a preset or a prescription file, which asphctl\n"
	  "reads and sends) on the plan of --method and one density. --tolerance takes\n"
	  "an ISO 10110-5 call-out ('3/2(0.5/0.3)'), JSON text or a file holding it; the\n"
	  "completed job then has a verdict. --for-tolerance lets the daemon choose the\n"
	  "plan for the tolerance on the instrument's uncertainty: the shortest whose U\n"
	  "(k = 2) is at most R T for every toleranced quantity (--capability, default\n"
	  "0.25; --method restricts the search to one method). --wait follows the job\n"
	  "as watch does (and exits as watch does), then prints the plan chosen for the\n"
	  "tolerance and why; --quiet leaves its progress out.\n",
	  cmd_submit_values },
	{ "status", "the daemon's status, or a job's", cmd_status,
	  "The daemon: version, queue, jobs by state, instruments. A job: its state, plan,\n"
	  "points, submitter, times and verdict; --history adds every transition.\n" },
	{ "watch", "follow a job until it ends", cmd_watch,
	  "Follows the job: a progress bar with points (or Monte Carlo trials), rate and\n"
	  "time left on a terminal, one line per percent otherwise; --quiet: the end\n"
	  "only. Exits 0 when the job completed (and its part passes), 3 when the part\n"
	  "fails its tolerance, 4 when the verdict is undecided, 5 when the job failed,\n"
	  "was cancelled or interrupted.\n" },
	{ "cancel", "cancel a job", cmd_cancel, NULL },
	{ "pause", "pause a running scan", cmd_pause,
	  "Pauses the job's scan at its next point; resume continues it.\n" },
	{ "resume", "resume a paused scan, or an interrupted job", cmd_resume,
	  "An interrupted job continues its recorded scan.\n" },
	{ "requeue", "queue a failed, interrupted or cancelled job again", cmd_requeue,
	  "The job continues its recorded scan, or with --restart records a new one.\n" },
	{ "list", "list jobs", cmd_list,
	  "Jobs, newest first, filtered by state, instrument, label, part, lot, serial or\n"
	  "your own (--mine). --csv prints every matching job as CSV (RFC 4180) unless\n"
	  "--limit is given.\n" },
	{ "result", "a job's result; --out DIR copies its files", cmd_result,
	  "The summary of a completed job: the fit, pose, residual, the ISO 14999-4\n"
	  "quantities, slope, the verdict with each toleranced quantity, the acquisition\n"
	  "and the scan's SHA-256. --out copies the result's files into DIR (created if\n"
	  "missing); --report writes its measurement report (PDF). A long copy shows its\n"
	  "progress on a terminal; --quiet leaves it out.\n" },
	{ "queue", "show the queue; move a job; start or stop the queue", cmd_queue,
	  "move JOB POSITION: position 0 runs next. stop --abort also stops running\n"
	  "scans, resumably.\n" },
	{ "instruments", "the instruments and their state", cmd_instruments, NULL },
	{ "drivers", "the drivers the daemon has", cmd_drivers, NULL },
	{ "lock", "lock an instrument for work at the machine", cmd_lock,
	  "No job starts on a locked instrument and others' changes to it are refused;\n"
	  "--pause also pauses its running scan. The reason is the rest of the line.\n" },
	{ "unlock", "end an instrument's lock", cmd_unlock,
	  "--force (admin) ends another's lock.\n" },
	{ "token", "create, list or revoke API tokens (root)", cmd_token,
	  "WHEN is a duration (90d, 12h) or a UTC date or time. The secret is printed\n"
	  "once.\n" },
	{ "fleet", "the newest results across daemons, from the central database", cmd_fleet,
	  "CONNINFO is a libpq connection string; without --db, $ASPHCTL_FLEET_DB, then\n"
	  "libpq's environment.\n" },
	{ "backup", "copy the daemon's job store into a file (root)", cmd_backup,
	  "A consistent copy of the job store (every job, its history, the tokens'\n"
	  "digests, the locks, the outbox) made while jobs run, written to FILE (mode\n"
	  "0600); prints the moment it is of, its size and its SHA-256. The restore is\n"
	  "in docs/admin.md. A long copy shows its progress on a terminal; --quiet\n"
	  "leaves it out.\n" },
	{ "health", "ok, degraded (with the reasons) or down, for monitoring", cmd_health,
	  "Prints ok (exit 0), degraded and a line per finding (exit 8), or down when\n"
	  "the daemon cannot be reached or does not answer within --timeout seconds,\n"
	  "10 by default (exit 7). The checks are in docs/admin.md.\n" },
	{ "help", "the usage of asphctl or of a command; help exit-status: the exit codes",
	  cmd_help, NULL },
};

static void usage(FILE *f)
{
	fprintf(f, "Usage: asphctl [--socket PATH] [--json] COMMAND [ARGS...]\n"
		   "       asphctl help [COMMAND]\n\n"
		   "Client of the asphd measurement daemon.\n\n"
		   "  -s, --socket PATH   the daemon's socket (default $ASPHD_SOCKET or %s)\n"
		   "  -j, --json          print results as JSON\n"
		   "      --version       print the version\n\n"
		   "Commands:\n", PROTO_DEFAULT_SOCKET);
	for (size_t i = 0; i < ARRAY_SIZE(commands); i++)
		fprintf(f, "  %-12s %s\n", commands[i].name, commands[i].summary);
	fprintf(f, "\nRun 'asphctl help COMMAND' for a command's options, 'asphctl help\n"
		   "exit-status' for the exit codes. The manual page is asphctl(1).\n");
}

static int run(struct ctl *ctl, const struct ctl_command *c, int argc, char **argv)
{
	int r;

	ctl->command = c;
	optind = 0;   /* reset getopt for the command */
	r = c->run(ctl, argc, argv);
	conn_close(ctl->conn);
	ctl->conn = NULL;
	return r;
}

/* asphctl help [COMMAND [SUBCOMMAND]]: the command's own --help. */
static int cmd_help(struct ctl *ctl, int argc, char **argv)
{
	const struct ctl_command *c;
	char *words[4];
	int n, r;

	if ((r = command_help("asphctl", COMMAND_TABLE(commands), usage, argc, argv,
			      (const void **)&c, words, &n)) >= 0)
		return r;
	if (c->run == cmd_help)
		return cmd_help(ctl, 1, argv);
	return run(ctl, c, n, words);
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
	const struct ctl_command *c;
	char why[256];
	int o;

	if (!ctl.socket || !*ctl.socket)
		ctl.socket = PROTO_DEFAULT_SOCKET;
	/* Options before the command only; the command parses the rest. */
	opterr = 0;
	while ((o = getopt_long(argc, argv, "+s:jh", opts, NULL)) != -1) {
		switch (o) {
		case 's': ctl.socket = optarg; break;
		case 'j': ctl.json = true; break;
		case 'V': printf("asphctl %s\n", ASPH_VERSION); return EXIT_OK;
		case 'h': usage(stdout); return EXIT_OK;
		default:
			fprintf(stderr, "asphctl: %s\nRun 'asphctl help' for the options.\n",
				suggest_getopt_error(argv, "+s:jh", opts, why, sizeof(why)));
			return EXIT_USAGE;
		}
	}
	if (optind >= argc) {
		usage(stderr);
		return EXIT_USAGE;
	}
	if (!(c = command_find(COMMAND_TABLE(commands), argv[optind])))
		return command_unknown("asphctl", argv[optind], COMMAND_TABLE(commands));
	return run(&ctl, c, argc - optind, argv + optind);
}
