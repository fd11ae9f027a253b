/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asphctl: the client of asphd. One file per group of commands. */
#ifndef ASPHCTL_H
#define ASPHCTL_H

#include <stdbool.h>
#include <stdint.h>
#include <sys/types.h>

#include <jansson.h>

#include "asph-proto.h"
#include "exit-codes.h"

/* A connection to the daemon. */
struct conn;

struct ctl_error {
	int code;               /* protocol error code, 0 for I/O */
	char message[128];
	char detail[512];
};

int conn_open(const char *path, struct conn **out, struct ctl_error *e);
/* The same, waiting at most timeout_ms (-1: no limit) for the connection
 * and for each answer of conn_call(), which then fails with -ETIMEDOUT. */
int conn_open_within(const char *path, int timeout_ms, struct conn **out, struct ctl_error *e);
void conn_close(struct conn *c);
/*
 * Calls method with params (stolen, may be NULL) and waits for its
 * response; notifications that arrive meanwhile are kept for
 * conn_next_event(). Returns 0 with *result (caller owns), -EPROTO for an
 * error response (e filled), or -errno when the connection failed.
 */
int conn_call(struct conn *c, const char *method, json_t *params,
	      json_t **result, struct ctl_error *e);
/* The same, passing n_fds descriptors (at most CONN_MAX_FDS) with the
 * request (SCM_RIGHTS): the request names them by their index. */
#define CONN_MAX_FDS 4
int conn_call_fds(struct conn *c, const char *method, json_t *params, const int *fds,
		  size_t n_fds, json_t **result, struct ctl_error *e);
/* Next notification: 1 with *msg, 0 on timeout (ms, -1 = none), or -errno. */
int conn_next_event(struct conn *c, int timeout_ms, json_t **msg);

struct ctl;

/* A command: its name, the summary `asphctl --help` lists, its function,
 * what `asphctl help COMMAND` says after the usage line (NULL: the usage
 * line says all), and the values of its operands and options that come
 * from a table (NULL: none), printed after that. */
struct ctl_command {
	const char *name;
	const char *summary;
	int (*run)(struct ctl *ctl, int argc, char **argv);
	const char *help;
	void (*help_values)(FILE *out);
};

/* Global options. */
struct ctl {
	const char *socket;
	bool json;
	struct conn *conn;
	const struct ctl_command *command;      /* the one running */
};

/* Prints e as "asphctl: ..." and returns the exit code it means. */
int ctl_fail(const struct ctl_error *e);
/* Connects (once) and calls; on failure prints and returns the exit code
 * (> 0), else 0 with *result. */
int ctl_call(struct ctl *ctl, const char *method, json_t *params,
	     json_t **result);
/* The same, passing n_fds descriptors with the request (conn_call_fds()). */
int ctl_call_fds(struct ctl *ctl, const char *method, json_t *params, const int *fds,
		 size_t n_fds, json_t **result);
/* Prints JSON (pretty) to stdout, with the characters that ctl_escape()
 * escapes written as \u escapes. */
void ctl_print_json(const json_t *j);
/* s with its control characters (C0, DEL, C1, bidirectional overrides)
 * escaped (malloc'd, or NULL): as \n, \t, \xNN or \uNNNN, or with json
 * all as \uNNNN (for the inside of a JSON string). */
char *ctl_escape(const char *s, bool json);
/* Every string (and key) in j escaped as ctl_escape() does, for printing
 * as text. */
void ctl_escape_json(json_t *j);
/* Whole-string conversions: 0, or -EINVAL for an empty string, trailing
 * characters, a value out of [min, max] (or out of range of the type), or
 * a real that is not finite. */
int ctl_parse_integer(const char *arg, long long min, long long max, long long *v);
int ctl_parse_real(const char *arg, double *v);
/* --- the options (options.c) */
struct option;
#define CTL_JSON_OPTION { "json", no_argument, NULL, 'j' }
#define CTL_HELP_OPTION { "help", no_argument, NULL, 'h' }
enum { CTL_OPTIONS_END = -1, CTL_OPTIONS_HELP = -2, CTL_OPTIONS_BAD = -3 };
/* Prints "Usage: asphctl USAGE" on stderr: EXIT_USAGE. */
int ctl_usage_error(const char *usage);
/*
 * The next option of a command (getopt_long() over opts, which hold
 * CTL_JSON_OPTION and CTL_HELP_OPTION, and shortopts without "jh"). --json
 * and --help are taken here. Returns the option's character for the
 * command, or CTL_OPTIONS_END when the options are over, CTL_OPTIONS_HELP
 * after printing the usage, CTL_OPTIONS_BAD after an unknown option or a
 * missing argument (the usage went to stderr).
 */
int ctl_option(struct ctl *ctl, int argc, char **argv, const char *shortopts,
	       const struct option *opts, const char *usage);
/* The exit code once ctl_option() returned c < 0: -1 when the command goes
 * on (CTL_OPTIONS_END). */
int ctl_options_exit(int c);
/* For a command whose only options are --json and --help: -1 to go on, or
 * the exit code. */
int ctl_common_options(struct ctl *ctl, int argc, char **argv, const char *usage);
/* For a command whose options are --json, --help and one flag --NAME
 * (short: its short form, or 0 for none): *set when it is given; -1 to go
 * on, or the exit code. */
int ctl_flag_option(struct ctl *ctl, int argc, char **argv, const char *name, char short_name,
		    bool *set, const char *usage);

/* Parses a job id argument; -1 (after printing) when it is not one. */
int64_t ctl_job_id(const char *arg);
/* The one operand after the options, a job id; -1 (after printing usage,
 * "Usage: asphctl USAGE", or why) when there is not exactly one or it is
 * not a job id. */
int64_t ctl_job_operand(int argc, char **argv, const char *usage);

int cmd_submit(struct ctl *ctl, int argc, char **argv);
void cmd_submit_values(FILE *out);
int cmd_status(struct ctl *ctl, int argc, char **argv);
int cmd_watch(struct ctl *ctl, int argc, char **argv);
int cmd_cancel(struct ctl *ctl, int argc, char **argv);
int cmd_pause(struct ctl *ctl, int argc, char **argv);
int cmd_resume(struct ctl *ctl, int argc, char **argv);
int cmd_requeue(struct ctl *ctl, int argc, char **argv);
int cmd_list(struct ctl *ctl, int argc, char **argv);
int cmd_result(struct ctl *ctl, int argc, char **argv);
int cmd_queue(struct ctl *ctl, int argc, char **argv);
int cmd_instruments(struct ctl *ctl, int argc, char **argv);
int cmd_drivers(struct ctl *ctl, int argc, char **argv);
int cmd_lock(struct ctl *ctl, int argc, char **argv);
int cmd_unlock(struct ctl *ctl, int argc, char **argv);
int cmd_token(struct ctl *ctl, int argc, char **argv);
int cmd_fleet(struct ctl *ctl, int argc, char **argv);
int cmd_backup(struct ctl *ctl, int argc, char **argv);
int cmd_health(struct ctl *ctl, int argc, char **argv);

/* A file the daemon hands in pieces (job.file, backup.file): method's
 * answers to params, each with its "offset" added, written to the path out
 * (mode before the umask) under a temporary name created exclusively and
 * renamed into place (fs_write_file_at()), its progress on a terminal
 * unless quiet. name is the file in messages. Returns the exit code,
 * having said why. */
int ctl_fetch_file(struct ctl *ctl, const char *method, const json_t *params, const char *name,
		   const char *out, mode_t mode, bool quiet);

/* Watches job until it ends (used by watch and submit --wait): its states
 * and, with progress, its progress; with --json only the job at the end.
 * The exit code: 0 completed (and its part passes), EXIT_VERDICT_FAIL,
 * EXIT_VERDICT_UNDECIDED, EXIT_JOB_FAILED, or a failed call's. */
int ctl_watch_job(struct ctl *ctl, int64_t id, bool progress);
/* One line per job for list and queue. */
void ctl_print_job_line(const json_t *job);

#endif
