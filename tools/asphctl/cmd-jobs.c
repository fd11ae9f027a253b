/* SPDX-License-Identifier: GPL-3.0-or-later */
/* submit, status, cancel, pause, resume, requeue, list, result. */
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <libgen.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "asph-names.h"
#include "asph/tolerance.h"
#include "asphctl.h"
#include "command.h"
#include "fit-summary.h"
#include "progress.h"
#include "util-fs.h"
#include "util-mem.h"

static const char *str(const json_t *o, const char *key)
{
	const char *s = json_string_value(json_object_get(o, key));

	return s ? s : "-";
}

/* A plan for the tolerance: "plan for the tolerance (U <= 0.25 T, ci)". */
static bool plan_for_tolerance(const json_t *plan, char *buf, size_t size)
{
	if (!json_is_true(json_object_get(plan, "for_tolerance")))
		return false;
	snprintf(buf, size, "for the tolerance (U <= %g T%s%s)",
		 json_number_value(json_object_get(plan, "capability")),
		 json_is_string(json_object_get(plan, "method")) ? ", " : "",
		 json_is_string(json_object_get(plan, "method")) ? str(plan, "method") : "");
	return true;
}

void ctl_print_job_line(const json_t *job)
{
	json_t *p = json_object_get(job, "progress");
	json_int_t done = json_integer_value(json_object_get(p, "done"));
	json_int_t total = json_integer_value(json_object_get(p, "total"));
	json_t *plan = json_object_get(job, "plan");
	char density[64];

	if (json_is_true(json_object_get(plan, "for_tolerance")))
		snprintf(density, sizeof(density), "for-tolerance %g",
			 json_number_value(json_object_get(plan, "capability")));
	else if (json_is_object(json_object_get(job, "measured")))
		snprintf(density, sizeof(density), "measured %s",
			 str(json_object_get(job, "measured"), "format"));
	else
		snprintf(density, sizeof(density), "%s %s=%g", str(plan, "method"),
			 str(plan, "density"), json_number_value(json_object_get(plan, "value")));
	printf("%6lld  %-11s %-10s %-14s %-20s %4lld  %7lld/%-7lld %s\n",
	       (long long)json_integer_value(json_object_get(job, "id")), str(job, "state"),
	       str(job, "instrument"), str(job, "lens"), density,
	       (long long)json_integer_value(json_object_get(job, "priority")),
	       (long long)done, (long long)total,
	       json_is_string(json_object_get(job, "label")) ? str(job, "label") : "");
}

static void print_job_header(void)
{
	printf("%6s  %-11s %-10s %-14s %-20s %4s  %15s %s\n", "ID", "STATE", "INSTRUMENT",
	       "LENS", "PLAN", "PRIO", "POINTS", "LABEL");
}

static void print_job(const json_t *job)
{
	json_t *p = json_object_get(job, "progress");
	json_t *sub = json_object_get(job, "submitter");

	printf("job %lld: %s\n", (long long)json_integer_value(json_object_get(job, "id")),
	       str(job, "state"));
	printf("  instrument  %s\n", str(job, "instrument"));
	printf("  lens        %s\n", str(job, "lens"));
	char tol[96];
	json_t *measured = json_object_get(job, "measured");
	if (json_is_object(measured))
		printf("  measured    %s data, %s in the job's folder\n", str(measured, "format"),
		       str(measured, "file"));
	else if (plan_for_tolerance(json_object_get(job, "plan"), tol, sizeof(tol)))
		printf("  plan        %s\n", tol);
	else
		printf("  plan        %s, %s = %g\n", str(json_object_get(job, "plan"), "method"),
		       str(json_object_get(job, "plan"), "density"),
		       json_number_value(json_object_get(json_object_get(job, "plan"), "value")));
	const char *phase = json_string_value(json_object_get(p, "phase"));
	printf(phase && !strcmp(phase, "planning") ? "  plan search %lld of at most %lld "
	       "characterizations\n" : "  points      %lld of %lld\n",
	       (long long)json_integer_value(json_object_get(p, "done")),
	       (long long)json_integer_value(json_object_get(p, "total")));
	if (json_is_object(json_object_get(p, "trials")))
		printf("  uncertainty %lld of %lld trials\n",
		       (long long)json_integer_value(json_object_get(json_object_get(p, "trials"),
								     "done")),
		       (long long)json_integer_value(json_object_get(json_object_get(p, "trials"),
								     "planned")));
	printf("  submitted   %s by %s\n", str(job, "submitted"), str(sub, "name"));
	printf("  started     %s\n", str(job, "started"));
	printf("  finished    %s\n", str(job, "finished"));
	if (json_is_string(json_object_get(job, "label")))
		printf("  label       %s\n", str(job, "label"));
	for (const char *const *k = (const char *const[]){ "part", "lot", "serial", NULL }; *k; k++)
		if (json_is_string(json_object_get(job, *k)))
			printf("  %-11s %s\n", *k, str(job, *k));
	if (json_is_string(json_object_get(job, "reason")))
		printf("  reason      %s\n", str(job, "reason"));
	if (json_is_string(json_object_get(job, "verdict")))
		printf("  verdict     %s\n", str(job, "verdict"));
	else if (json_object_get(job, "tolerance") && !json_is_null(json_object_get(job, "tolerance")))
		printf("  verdict     (toleranced; decided when the job completes)\n");
}

/* Why JSON text could not be read, with where when jansson knows it
 * (asph_error_format() leaves an unknown line or column out). */
static void json_load_failed(const char *what, const char *source, const json_error_t *e)
{
	struct asph_error err;
	char buf[600];

	asph_error_clear(&err);
	asph_error_set_at(&err, -EINVAL, source, e->line, e->column, NULL, "%s", e->text);
	fprintf(stderr, "asphctl: %s%s%s\n", what ? what : "", what ? ": " : "",
		asph_error_format(&err, buf, sizeof(buf)));
}

/* LENS: a file the client reads (sent as the prescription), else a
 * preset name. */
static json_t *lens_param(const char *lens)
{
	struct stat st;
	json_error_t e;
	json_t *j;

	if (stat(lens, &st) != 0 || !S_ISREG(st.st_mode))
		return json_string(lens);
	j = json_load_file(lens, JSON_REJECT_DUPLICATES, &e);
	if (!j)
		json_load_failed(NULL, lens, &e);
	return j;
}

/* The daemon checks ranges (and names the parameter); these only refuse
 * what is not a number at all, so nothing is sent as 0 or clipped. */
static bool set_integer(json_t *obj, const char *key, const char *arg)
{
	long long v;

	if (ctl_parse_integer(arg, LLONG_MIN, LLONG_MAX, &v) < 0) {
		fprintf(stderr, "asphctl: --%s: '%s' is not an integer\n", key, arg);
		return false;
	}
	json_object_set_new(obj, key, json_integer(v));
	return true;
}

static bool set_real(json_t *obj, const char *key, const char *arg)
{
	double v;

	if (ctl_parse_real(arg, &v) < 0) {
		fprintf(stderr, "asphctl: --%s: '%s' is not a finite number\n", key, arg);
		return false;
	}
	json_object_set_new(obj, key, json_real(v));
	return true;
}

/* --tolerance, by the rule of asph_tolerance_arg_kind(): a call-out is sent
 * as a string (as the web page sends it), JSON text or a file's JSON as it
 * is; the daemon checks it. */
static json_t *tolerance_param(const char *arg)
{
	json_error_t e;
	json_t *j = NULL;

	if (!arg[strspn(arg, " \t\r\n")]) {
		fprintf(stderr, "asphctl: --tolerance: empty: give an ISO 10110-5 call-out, JSON "
				"text or a file holding it\n");
		return NULL;
	}
	switch (asph_tolerance_arg_kind(arg)) {
	case ASPH_TOLERANCE_ARG_CALLOUT:
		return json_string(arg + strspn(arg, " \t\r\n"));
	case ASPH_TOLERANCE_ARG_JSON:
		j = json_loads(arg, JSON_DECODE_ANY | JSON_REJECT_DUPLICATES, &e);
		break;
	case ASPH_TOLERANCE_ARG_FILE:
		j = json_load_file(arg, JSON_DECODE_ANY | JSON_REJECT_DUPLICATES, &e);
		break;
	}
	if (!j)
		json_load_failed("--tolerance", asph_tolerance_arg_kind(arg) == ASPH_TOLERANCE_ARG_JSON
						? "<tolerance>" : arg, &e);
	return j;
}

static const char submit_usage[] =
	"submit LENS (--method M (--h H | --spacing MM | --points N) [--profiles N]\n"
	"             | --for-tolerance [--capability R] [--method M]\n"
	"             | --measured FILE [--format F] [--units U])\n"
	"       [--instrument NAME] [--priority P] [--label TEXT] [--dof LIST]\n"
	"       [--residual " NAMES_RESIDUALS "] [--robust] [--zernike N] [--tolerance T]\n"
	"       [--part P] [--lot L] [--serial S] [--wait [--quiet]] [--json]";

/* The presets and plan methods, from libasph's tables (print-names). */
void cmd_submit_values(FILE *out)
{
	command_help_option(out, "LENS", "a preset (" NAMES_PRESETS ") or a prescription file");
	command_help_option(out, "--method M", NAMES_PLAN_METHODS);
	command_help_option(out, "--measured FILE", "measured data the daemon characterizes "
			    "instead of measuring (asphctl opens it and passes it to the "
			    "daemon, which must run on this machine)");
	command_help_option(out, "--format F", NAMES_POINTS_FORMATS);
	command_help_option(out, "--units U", NAMES_POINTS_UNITS);
}

/* --measured FILE: the file opened here, passed to the daemon as
 * descriptor 0 of the request; -1 after saying why. */
static int measured_param(json_t *params, const char *path, const char *format,
			  const char *units)
{
	int fd = open(path, O_RDONLY | O_CLOEXEC);
	struct stat st;

	if (fd < 0 || fstat(fd, &st) < 0 || S_ISDIR(st.st_mode)) {
		fprintf(stderr, "asphctl: submit: --measured: %s: %s\n", path,
			fd < 0 || !S_ISDIR(st.st_mode) ? strerror(errno) : "a directory");
		if (fd >= 0)
			close(fd);
		return -1;
	}
	json_object_set_new(params, "measured", json_pack("{s:i, s:s*, s:s*}", "fd", 0,
							   "format", format, "units", units));
	return fd;
}

/* "job 12 queued (700 points, about 1 min 15 s to measure)". */
static void print_queued(const json_t *job, json_int_t id)
{
	json_t *est = json_object_get(job, "estimate_s");
	char tol[96];

	if (plan_for_tolerance(json_object_get(job, "plan"), tol, sizeof(tol))) {
		printf("job %lld queued: its plan is chosen %s when it runs\n", (long long)id,
		       tol);
		return;
	}
	long long n = (long long)json_integer_value(json_object_get(json_object_get(job, "progress"),
								     "total"));

	if (json_is_object(json_object_get(job, "measured"))) {
		printf("job %lld queued (%lld measured points to characterize)\n", (long long)id, n);
		return;
	}

	if (json_is_number(est)) {
		double t = json_number_value(est);
		long long s = (long long)(t + 0.5);
		if (s >= 3600)
			printf("job %lld queued (%lld points, about %lld h %02lld min to measure)\n",
			       (long long)id, n, s / 3600, s / 60 % 60);
		else
			printf("job %lld queued (%lld points, about %lld min %02lld s to measure)\n",
			       (long long)id, n, s / 60, s % 60);
	} else {
		printf("job %lld queued (%lld points; no estimate of the measuring time)\n",
		       (long long)id, n);
	}
}

/* The plan the daemon chose for the tolerance, and why: each quantity's
 * U and U/T, and what became of the other methods. */
static void print_choice(const json_t *ch)
{
	const json_t *plan = json_object_get(ch, "plan"), *q, *m;
	size_t i;

	printf("plan for the tolerance: %s, h = %.4g, %lld points, %.1f s to measure "
	       "(U <= %g T for every quantity, k = 2)\n", str(plan, "method"),
	       json_number_value(json_object_get(plan, "h")),
	       (long long)json_integer_value(json_object_get(plan, "points")),
	       json_number_value(json_object_get(ch, "estimate_s")),
	       json_number_value(json_object_get(ch, "capability")));
	printf("  %-16s %12s %12s %8s\n", "quantity", "T", "U (k = 2)", "U/T");
	json_array_foreach(json_object_get(ch, "quantities"), i, q)
		printf("  %-16s %12.4g %12.4g %8.3f\n", str(q, "quantity"),
		       json_number_value(json_object_get(q, "limit")),
		       json_number_value(json_object_get(q, "U")),
		       json_number_value(json_object_get(q, "ratio")));
	json_array_foreach(json_object_get(ch, "methods"), i, m) {
		const char *outcome = str(m, "outcome");
		if (!strcmp(outcome, "chosen") || !strcmp(outcome, "not-tried"))
			continue;
		printf("  %-10s %s: %lld points, %.1f s", str(m, "method"), outcome,
		       (long long)json_integer_value(json_object_get(m, "points")),
		       json_number_value(json_object_get(m, "estimate_s")));
		if (json_is_number(json_object_get(m, "ratio")))
			printf(", U/T %.3f", json_number_value(json_object_get(m, "ratio")));
		printf("\n");
	}
}

/* After --wait: the plan chosen for the tolerance, when there is one. */
static void show_choice(struct ctl *ctl, json_int_t id)
{
	_cleanup_(json_decrefp) json_t *result = NULL;
	json_t *ch;

	if (ctl_call(ctl, "job.result", json_pack("{s:I}", "id", id), &result) != 0)
		return;
	ch = json_object_get(result, "plan_for_tolerance");
	if (json_is_object(ch))
		print_choice(ch);
}

/* --for-tolerance: no density; a tolerance; --capability in (0, 1]. */
static bool for_tolerance_ok(json_t *params, json_t *plan, const char *capability)
{
	static const char *const density[] = { "h", "spacing", "points", "profiles" };
	double v = 0.25;

	for (size_t i = 0; i < ARRAY_SIZE(density); i++)
		if (json_object_get(plan, density[i])) {
			fprintf(stderr, "asphctl: submit: --%s: --for-tolerance chooses the plan's "
				"density itself\n", density[i]);
			return false;
		}
	if (!json_object_get(params, "tolerance")) {
		fprintf(stderr, "asphctl: submit: --for-tolerance chooses the plan for the part's "
			"tolerance: give it with --tolerance\n");
		return false;
	}
	if (capability && (ctl_parse_real(capability, &v) < 0 || !(v > 0 && v <= 1))) {
		fprintf(stderr, "asphctl: submit: --capability: '%s' is not in (0, 1]: the largest "
			"U (k = 2) of each quantity, as a fraction of its tolerance T\n", capability);
		return false;
	}
	json_object_set_new(plan, "for_tolerance", json_true());
	if (capability)
		json_object_set_new(plan, "capability", json_real(v));
	return true;
}

int cmd_submit(struct ctl *ctl, int argc, char **argv)
{
	static const struct option opts[] = {
		{ "method", required_argument, NULL, 'm' },
		{ "h", required_argument, NULL, 'H' },
		{ "spacing", required_argument, NULL, 'S' },
		{ "points", required_argument, NULL, 'P' },
		{ "profiles", required_argument, NULL, 'F' },
		{ "instrument", required_argument, NULL, 'i' },
		{ "priority", required_argument, NULL, 'p' },
		{ "label", required_argument, NULL, 'l' },
		{ "dof", required_argument, NULL, 'd' },
		{ "residual", required_argument, NULL, 'r' },
		{ "robust", no_argument, NULL, 'R' },
		{ "zernike", required_argument, NULL, 'z' },
		{ "part", required_argument, NULL, 'A' },
		{ "lot", required_argument, NULL, 'L' },
		{ "serial", required_argument, NULL, 'N' },
		{ "tolerance", required_argument, NULL, 't' },
		{ "for-tolerance", no_argument, NULL, 'T' },
		{ "capability", required_argument, NULL, 'C' },
		{ "measured", required_argument, NULL, 'M' },
		{ "format", required_argument, NULL, 'O' },
		{ "units", required_argument, NULL, 'U' },
		{ "wait", no_argument, NULL, 'w' },
		{ "quiet", no_argument, NULL, 'q' },
		CTL_JSON_OPTION, CTL_HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	_cleanup_(json_decrefp) json_t *params = json_object();
	_cleanup_(json_decrefp) json_t *result = NULL;
	_cleanup_close_ int data = -1;
	json_t *plan = json_object(), *fit = json_object();
	bool wait = false, quiet = false, for_tolerance = false;
	const char *capability = NULL, *measured = NULL, *format = NULL, *units = NULL;
	int c, r;

	json_object_set_new(params, "plan", plan);
	while ((c = ctl_option(ctl, argc, argv, "m:i:p:l:q", opts, submit_usage)) > 0) {
		bool ok = true;
		switch (c) {
		case 'm': json_object_set_new(plan, "method", json_string(optarg)); break;
		case 'H': ok = set_real(plan, "h", optarg); break;
		case 'S': ok = set_real(plan, "spacing", optarg); break;
		case 'P': ok = set_real(plan, "points", optarg); break;
		case 'F': ok = set_integer(plan, "profiles", optarg); break;
		case 'i': json_object_set_new(params, "instrument", json_string(optarg)); break;
		case 'p': ok = set_integer(params, "priority", optarg); break;
		case 'l': json_object_set_new(params, "label", json_string(optarg)); break;
		case 'd': json_object_set_new(fit, "dof", json_string(optarg)); break;
		case 'r': json_object_set_new(fit, "residual", json_string(optarg)); break;
		case 'R': json_object_set_new(fit, "robust", json_true()); break;
		case 'z': ok = set_integer(fit, "zernike", optarg); break;
		case 'A': json_object_set_new(params, "part", json_string(optarg)); break;
		case 'L': json_object_set_new(params, "lot", json_string(optarg)); break;
		case 'N': json_object_set_new(params, "serial", json_string(optarg)); break;
		case 't': {
			json_t *t = tolerance_param(optarg);
			ok = t != NULL;
			if (t)
				json_object_set_new(params, "tolerance", t);
			break;
		}
		case 'T': for_tolerance = true; break;
		case 'C': capability = optarg; break;
		case 'M': measured = optarg; break;
		case 'O': format = optarg; break;
		case 'U': units = optarg; break;
		case 'w': wait = true; break;
		case 'q': quiet = true; break;
		}
		if (!ok) {
			json_decref(fit);
			return EXIT_USAGE;
		}
	}
	if (c != CTL_OPTIONS_END) {
		json_decref(fit);
		return ctl_options_exit(c);
	}
	if (optind + 1 != argc || (capability && !for_tolerance) ||
	    ((format || units) && !measured) ||
	    (measured && (for_tolerance || json_object_size(plan)))) {
		json_decref(fit);
		return ctl_usage_error(submit_usage);
	}
	if (measured) {
		json_object_del(params, "plan");
		data = measured_param(params, measured, format, units);
		if (data < 0) {
			json_decref(fit);
			return EXIT_FAILURE_RUN;
		}
	}
	if (for_tolerance && !for_tolerance_ok(params, plan, capability)) {
		json_decref(fit);
		return EXIT_USAGE;
	}
	if (json_object_size(fit))
		json_object_set_new(params, "fit", fit);
	else
		json_decref(fit);
	json_t *lens = lens_param(argv[optind]);
	if (!lens)
		return EXIT_FAILURE_RUN;
	json_object_set_new(params, "lens", lens);
	r = ctl_call_fds(ctl, "job.submit", json_incref(params), &data, data >= 0 ? 1 : 0,
			 &result);
	if (r)
		return r;
	json_int_t id = json_integer_value(json_object_get(result, "id"));
	if (ctl->json && !wait)
		ctl_print_json(result);
	else if (!ctl->json)
		print_queued(result, id);
	fflush(stdout);
	if (!wait)
		return EXIT_OK;
	r = ctl_watch_job(ctl, id, !quiet);
	if (for_tolerance && !ctl->json)
		show_choice(ctl, id);
	return r;
}

/* Commands that take JOB and [--json] and call one method. */
static int simple_job_command(struct ctl *ctl, int argc, char **argv, const char *method,
			      const char *usage, const char *done)
{
	_cleanup_(json_decrefp) json_t *result = NULL;
	int64_t id;
	int c, r;

	if ((c = ctl_common_options(ctl, argc, argv, usage)) >= 0)
		return c;
	if ((id = ctl_job_operand(argc, argv, usage)) < 0)
		return EXIT_USAGE;
	r = ctl_call(ctl, method, json_pack("{s:I}", "id", (json_int_t)id), &result);
	if (r)
		return r;
	if (ctl->json)
		ctl_print_json(result);
	else
		printf("job %lld %s (%s)\n", (long long)id, done, str(result, "state"));
	return EXIT_OK;
}

int cmd_cancel(struct ctl *ctl, int argc, char **argv)
{
	return simple_job_command(ctl, argc, argv, "job.cancel", "cancel JOB [--json]",
				  "cancel requested");
}

int cmd_pause(struct ctl *ctl, int argc, char **argv)
{
	return simple_job_command(ctl, argc, argv, "job.pause", "pause JOB [--json]", "pausing");
}

int cmd_resume(struct ctl *ctl, int argc, char **argv)
{
	return simple_job_command(ctl, argc, argv, "job.resume", "resume JOB [--json]", "resumed");
}

int cmd_requeue(struct ctl *ctl, int argc, char **argv)
{
	static const char usage[] = "requeue JOB [--restart] [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	bool restart = false;
	int64_t id;
	int c, r;

	if ((c = ctl_flag_option(ctl, argc, argv, "restart", 'r', &restart, usage)) >= 0)
		return c;
	if ((id = ctl_job_operand(argc, argv, usage)) < 0)
		return EXIT_USAGE;
	r = ctl_call(ctl, "job.requeue",
		     json_pack("{s:I, s:b}", "id", (json_int_t)id, "restart", restart), &result);
	if (r)
		return r;
	if (ctl->json)
		ctl_print_json(result);
	else
		printf("job %lld queued again%s\n", (long long)id,
		       restart ? " (new scan)" : json_is_true(json_object_get(result, "resumable"))
						 ? " (continues its scan)" : "");
	return EXIT_OK;
}

int cmd_status(struct ctl *ctl, int argc, char **argv)
{
	static const char usage[] = "status [JOB [--history]] [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	bool history = false;
	int c, r;

	if ((c = ctl_flag_option(ctl, argc, argv, "history", 0, &history, usage)) >= 0)
		return c;
	if (optind + 1 == argc) {
		int64_t id = ctl_job_id(argv[optind]);
		if (id < 0)
			return EXIT_USAGE;
		r = ctl_call(ctl, "job.get", json_pack("{s:I, s:b}", "id", (json_int_t)id,
						       "history", history), &result);
		if (r)
			return r;
		if (ctl->json) {
			ctl_print_json(result);
			return EXIT_OK;
		}
		print_job(result);
		size_t i;
		json_t *h;
		json_array_foreach(json_object_get(result, "history"), i, h)
			printf("  %s  %-11s %-16s %s\n", str(h, "time"), str(h, "state"),
			       json_is_string(json_object_get(h, "actor")) ? str(h, "actor") : "-",
			       json_is_string(json_object_get(h, "reason")) ? str(h, "reason") : "");
		return EXIT_OK;
	}
	if (optind != argc)
		return ctl_usage_error(usage);
	r = ctl_call(ctl, "daemon.status", NULL, &result);
	if (r)
		return r;
	if (ctl->json) {
		ctl_print_json(result);
		return EXIT_OK;
	}
	json_t *jobs = json_object_get(result, "jobs"), *in;
	size_t i;
	printf("asphd %s (pid %lld), up %.0f s: %s\n", str(result, "version"),
	       (long long)json_integer_value(json_object_get(result, "pid")),
	       json_number_value(json_object_get(result, "uptime_s")), str(result, "status"));
	printf("queue %s; jobs: %lld queued, %lld running, %lld paused, %lld interrupted, "
	       "%lld completed, %lld failed, %lld cancelled\n",
	       json_is_true(json_object_get(json_object_get(result, "queue"), "running"))
		       ? "running" : "stopped",
	       (long long)json_integer_value(json_object_get(jobs, "queued")),
	       (long long)json_integer_value(json_object_get(jobs, "running")),
	       (long long)json_integer_value(json_object_get(jobs, "paused")),
	       (long long)json_integer_value(json_object_get(jobs, "interrupted")),
	       (long long)json_integer_value(json_object_get(jobs, "completed")),
	       (long long)json_integer_value(json_object_get(jobs, "failed")),
	       (long long)json_integer_value(json_object_get(jobs, "cancelled")));
	json_array_foreach(json_object_get(result, "instruments"), i, in) {
		json_t *lock = json_object_get(in, "lock");
		printf("instrument %s: %s", str(in, "name"), str(in, "state"));
		if (json_is_integer(json_object_get(in, "job")))
			printf(" (job %lld)", (long long)json_integer_value(json_object_get(in, "job")));
		if (json_is_object(lock))
			printf(", locked by %s since %s: %s", str(lock, "holder"), str(lock, "since"),
			       str(lock, "reason"));
		printf("\n");
	}
	return EXIT_OK;
}

/* One CSV cell (RFC 4180): quoted when it holds a comma, a quote or a
 * line break. */
static void csv_cell(const char *t, bool last)
{
	if (strpbrk(t, ",\"\r\n")) {
		putchar('"');
		for (const char *c = t; *c; c++) {
			if (*c == '"')
				putchar('"');
			putchar(*c);
		}
		putchar('"');
	} else {
		fputs(t, stdout);
	}
	putchar(last ? '\n' : ',');
}

/* A text field: control characters escaped as ctl_escape() does (a tab
 * or a carriage return becomes \t, \x0d), and one that a spreadsheet
 * would take for a formula (it starts with = + - @, a tab or a carriage
 * return: OWASP's "CSV injection") starts with a ' so that it is shown as
 * the text it is. */
static void csv_field(const char *s, bool last)
{
	_cleanup_free_ char *e = ctl_escape(s ? s : "", false);
	_cleanup_free_ char *guarded = NULL;
	const char *t = e ? e : "";

	if (t[0] && strchr("=+-@\t\r", t[0]) && asprintf(&guarded, "'%s", t) >= 0)
		t = guarded;
	csv_cell(t, last);
}

static void csv_number(const json_t *v, bool last)
{
	char buf[32] = "";

	if (json_is_integer(v))
		snprintf(buf, sizeof(buf), "%lld", (long long)json_integer_value(v));
	else if (json_is_number(v))
		snprintf(buf, sizeof(buf), "%.17g", json_number_value(v));
	csv_cell(buf, last);
}

static const char csv_header[] =
	"id,state,verdict,instrument,lens,method,density,value,priority,points_done,"
	"points_total,submitted,started,finished,submitter_uid,submitter,label,reason\n";

static void csv_job(const json_t *job)
{
	const json_t *plan = json_object_get(job, "plan"), *p = json_object_get(job, "progress");
	const json_t *sub = json_object_get(job, "submitter");

	csv_number(json_object_get(job, "id"), false);
	csv_field(json_string_value(json_object_get(job, "state")), false);
	csv_field(json_string_value(json_object_get(job, "verdict")), false);
	csv_field(json_string_value(json_object_get(job, "instrument")), false);
	csv_field(json_string_value(json_object_get(job, "lens")), false);
	csv_field(json_string_value(json_object_get(plan, "method")), false);
	csv_field(json_string_value(json_object_get(plan, "density")), false);
	csv_number(json_object_get(plan, "value"), false);
	csv_number(json_object_get(job, "priority"), false);
	csv_number(json_object_get(p, "done"), false);
	csv_number(json_object_get(p, "total"), false);
	csv_field(json_string_value(json_object_get(job, "submitted")), false);
	csv_field(json_string_value(json_object_get(job, "started")), false);
	csv_field(json_string_value(json_object_get(job, "finished")), false);
	csv_number(json_object_get(sub, "uid"), false);
	csv_field(json_string_value(json_object_get(sub, "name")), false);
	csv_field(json_string_value(json_object_get(job, "label")), false);
	csv_field(json_string_value(json_object_get(job, "reason")), true);
}

/* --csv without --limit: every matching job, a page at a time. */
static int list_csv(struct ctl *ctl, json_t *params, bool all)
{
	json_int_t offset = json_integer_value(json_object_get(params, "offset"));

	fputs(csv_header, stdout);
	for (;;) {
		_cleanup_(json_decrefp) json_t *result = NULL;
		json_t *jobs, *job;
		size_t i;
		int r;

		if (all) {
			json_object_set_new(params, "offset", json_integer(offset));
			json_object_set_new(params, "limit", json_integer(1000));
		}
		r = ctl_call(ctl, "job.list", json_incref(params), &result);
		if (r)
			return r;
		jobs = json_object_get(result, "jobs");
		json_array_foreach(jobs, i, job)
			csv_job(job);
		offset += (json_int_t)json_array_size(jobs);
		if (!all || json_array_size(jobs) == 0 ||
		    offset >= json_integer_value(json_object_get(result, "total")))
			return EXIT_OK;
	}
}

int cmd_list(struct ctl *ctl, int argc, char **argv)
{
	static const struct option opts[] = {
		{ "state", required_argument, NULL, 's' },
		{ "instrument", required_argument, NULL, 'i' },
		{ "label", required_argument, NULL, 'l' },
		{ "mine", no_argument, NULL, 'm' },
		{ "part", required_argument, NULL, 'A' },
		{ "lot", required_argument, NULL, 'L' },
		{ "serial", required_argument, NULL, 'N' },
		{ "limit", required_argument, NULL, 'n' },
		{ "offset", required_argument, NULL, 'o' },
		{ "csv", no_argument, NULL, 'c' },
		CTL_JSON_OPTION, CTL_HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	static const char usage[] = "list [--state S[,S...]] [--instrument NAME] [--label TEXT]\n"
				    "       [--part P] [--lot L] [--serial S] [--mine] [--limit N]\n"
				    "       [--offset N] [--json | --csv]";
	_cleanup_(json_decrefp) json_t *params = json_object();
	_cleanup_(json_decrefp) json_t *result = NULL;
	bool csv = false;
	int c, r;

	while ((c = ctl_option(ctl, argc, argv, "s:i:l:mn:o:", opts, usage)) > 0) {
		switch (c) {
		case 's': {
			json_t *states = json_array();
			_cleanup_free_ char *copy = strdup(optarg);
			char *save = NULL;
			for (char *t = strtok_r(copy, ",", &save); t; t = strtok_r(NULL, ",", &save))
				json_array_append_new(states, json_string(t));
			json_object_set_new(params, "states", states);
			break;
		}
		case 'i': json_object_set_new(params, "instrument", json_string(optarg)); break;
		case 'l': json_object_set_new(params, "label", json_string(optarg)); break;
		case 'm': json_object_set_new(params, "mine", json_true()); break;
		case 'A': json_object_set_new(params, "part", json_string(optarg)); break;
		case 'L': json_object_set_new(params, "lot", json_string(optarg)); break;
		case 'N': json_object_set_new(params, "serial", json_string(optarg)); break;
		case 'n':
		case 'o': {
			long long v;
			if (ctl_parse_integer(optarg, 0, LLONG_MAX, &v) < 0) {
				fprintf(stderr, "asphctl: '%s' is not a count\n", optarg);
				return EXIT_USAGE;
			}
			json_object_set_new(params, c == 'n' ? "limit" : "offset", json_integer(v));
			break;
		}
		case 'c': csv = true; break;
		}
	}
	if (c != CTL_OPTIONS_END)
		return ctl_options_exit(c);
	if (optind != argc || (csv && ctl->json))
		return ctl_usage_error(usage);
	if (csv)
		return list_csv(ctl, params, !json_object_get(params, "limit"));
	r = ctl_call(ctl, "job.list", json_incref(params), &result);
	if (r)
		return r;
	if (ctl->json) {
		ctl_print_json(result);
		return EXIT_OK;
	}
	size_t i;
	json_t *job;
	print_job_header();
	json_array_foreach(json_object_get(result, "jobs"), i, job)
		ctl_print_job_line(job);
	printf("(%zu of %lld)\n", json_array_size(json_object_get(result, "jobs")),
	       (long long)json_integer_value(json_object_get(result, "total")));
	return EXIT_OK;
}

/* A file the daemon hands in pieces (job.file, backup.file): the answers
 * of method to params with each piece's "offset" added. */
struct fetch {
	struct ctl *ctl;
	const char *method;
	const json_t *params;
	const char *name;       /* for messages */
	bool quiet;             /* no progress line */
	int code;               /* the exit code when a call failed */
};

static int fetch_chunk_loop(struct fetch *fe, FILE *f, struct progress *p, json_int_t *offset,
			    struct asph_error *err)
{
	for (;;) {
		_cleanup_(json_decrefp) json_t *chunk = NULL;
		_cleanup_free_ void *bytes = NULL;
		json_t *params = json_deep_copy(fe->params);
		const char *text;
		size_t n = 0;

		if (!params || json_object_set_new(params, "offset", json_integer(*offset)) < 0) {
			json_decref(params);
			return asph_error_set(err, -ENOMEM, "out of memory");
		}
		fe->code = ctl_call(fe->ctl, fe->method, params, &chunk);
		if (fe->code)
			return asph_error_set(err, -EIO, "%s: the daemon did not send it", fe->name);
		text = json_string_value(json_object_get(chunk, "data"));
		if (!text || proto_base64_decode(text, strlen(text), &bytes, &n) < 0)
			return asph_error_set(err, -EBADMSG, "%s: the daemon sent no base64", fe->name);
		if (n && fwrite(bytes, 1, n, f) != n)
			return asph_error_set(err, -errno, "%s: %s", fe->name, strerror(errno));
		*offset += (json_int_t)n;
		progress_show(p, (size_t)*offset / 1024,
			      (size_t)json_integer_value(json_object_get(chunk, "size")) / 1024);
		if (json_is_true(json_object_get(chunk, "eof")) || n == 0)
			return 0;
	}
}

static int fetch_chunks(FILE *f, void *data, struct asph_error *err)
{
	struct fetch *fe = data;
	json_int_t offset = 0;
	struct progress p;
	int r;

	/* a scan of a million points is a long copy: its KiB on a terminal */
	progress_start(&p, fe->name, "KiB", fe->quiet);
	r = fetch_chunk_loop(fe, f, &p, &offset, err);
	progress_stop(&p);
	return r;
}

int ctl_fetch_file(struct ctl *ctl, const char *method, const json_t *params, const char *name,
		   const char *out, mode_t mode, bool quiet)
{
	_cleanup_free_ char *dcopy = strdup(out), *bcopy = strdup(out);
	_cleanup_close_ int dir = -1;
	struct fetch fe = { .ctl = ctl, .method = method, .params = params, .name = name,
			    .quiet = quiet };
	struct asph_error err;
	char buf[600];

	if (!dcopy || !bcopy)
		return EXIT_FAILURE_RUN;
	dir = open(dirname(dcopy), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
	if (dir < 0) {
		fprintf(stderr, "asphctl: %s: %s\n", out, strerror(errno));
		return EXIT_FAILURE_RUN;
	}
	asph_error_clear(&err);
	if (fs_write_file_at(dir, basename(bcopy), mode, fetch_chunks, &fe, &err) < 0) {
		if (fe.code)
			return fe.code;
		fprintf(stderr, "asphctl: %s: %s\n", out, asph_error_format(&err, buf, sizeof(buf)));
		return EXIT_FAILURE_RUN;
	}
	return EXIT_OK;
}

/*
 * Copies the files of job id's result into the directory out (created if
 * missing). The bytes come through the socket (job.file), so the caller
 * needs no access to the daemon's state directory. Each file is written
 * under a temporary name created exclusively in out and renamed into
 * place: a symlink planted in out is replaced, never written through.
 */
static int copy_files(struct ctl *ctl, int64_t id, const json_t *files, const char *out,
		      bool quiet)
{
	_cleanup_close_ int dir = -1;
	const char *key;
	json_t *v;

	if (mkdir(out, 0777) < 0 && errno != EEXIST) {
		fprintf(stderr, "asphctl: %s: %s\n", out, strerror(errno));
		return EXIT_FAILURE_RUN;
	}
	dir = open(out, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
	if (dir < 0) {
		fprintf(stderr, "asphctl: %s: %s\n", out, strerror(errno));
		return EXIT_FAILURE_RUN;
	}
	json_object_foreach((json_t *)files, key, v) {
		_cleanup_(json_decrefp) json_t *params = json_pack("{s:I, s:O}", "id",
								   (json_int_t)id, "name", v);
		struct fetch fe = { .ctl = ctl, .method = "job.file", .params = params,
				    .name = json_string_value(v), .quiet = quiet };
		struct asph_error err;
		char buf[600];

		asph_error_clear(&err);
		if (!fe.name || !params ||
		    fs_write_file_at(dir, fe.name, 0666, fetch_chunks, &fe, &err) < 0) {
			if (fe.code)
				return fe.code;
			fprintf(stderr, "asphctl: %s: %s\n", out,
				fe.name ? asph_error_format(&err, buf, sizeof(buf)) : "a file without a name");
			return EXIT_FAILURE_RUN;
		}
	}
	return EXIT_OK;
}

/* The result's file under key (e.g. "report") written to the path out,
 * as copy_files() writes each file. */
static int copy_file_to(struct ctl *ctl, int64_t id, const json_t *files, const char *key,
			const char *out, bool quiet)
{
	const char *name = json_string_value(json_object_get(files, key));
	_cleanup_(json_decrefp) json_t *params = NULL;

	if (!name) {
		fprintf(stderr, "asphctl: job %lld has no %s (a result without one: built without "
			"cairo, or before the daemon wrote one)\n", (long long)id, key);
		return EXIT_FAILURE_RUN;
	}
	params = json_pack("{s:I, s:s}", "id", (json_int_t)id, "name", name);
	if (!params)
		return EXIT_FAILURE_RUN;
	return ctl_fetch_file(ctl, "job.file", params, name, out, 0666, quiet);
}

static void print_summary(const json_t *res)
{
	json_t *s = json_object_get(res, "summary");
	json_t *prov = json_object_get(res, "provenance");

	printf("job %lld:\n", (long long)json_integer_value(json_object_get(res, "job")));
	fit_summary_print(stdout, s, "  ");
	fit_summary_print_acquisition(stdout, json_object_get(s, "acquisition"), "  ");
	if (json_is_object(json_object_get(prov, "measured")))
		printf("  Measured data %s, sha256 %s\n",
		       str(json_object_get(prov, "measured"), "file"),
		       str(json_object_get(prov, "measured"), "sha256"));
	else
		printf("  Scan sha256 %s\n", str(json_object_get(prov, "scan"), "sha256"));
	printf("  Files in %s\n", str(res, "dir"));
}

int cmd_result(struct ctl *ctl, int argc, char **argv)
{
	static const struct option opts[] = {
		{ "out", required_argument, NULL, 'o' },
		{ "report", required_argument, NULL, 'r' },
		{ "quiet", no_argument, NULL, 'q' }, CTL_JSON_OPTION, CTL_HELP_OPTION,
		{ NULL, 0, NULL, 0 },
	};
	static const char usage[] = "result JOB [--out DIR] [--report OUT.pdf] [--quiet] [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	const char *out = NULL, *report = NULL;
	bool quiet = false;
	int64_t id;
	int c, r;

	while ((c = ctl_option(ctl, argc, argv, "o:q", opts, usage)) > 0) {
		switch (c) {
		case 'o': out = optarg; break;
		case 'r': report = optarg; break;
		case 'q': quiet = true; break;
		}
	}
	if (c != CTL_OPTIONS_END)
		return ctl_options_exit(c);
	if ((id = ctl_job_operand(argc, argv, usage)) < 0)
		return EXIT_USAGE;
	r = ctl_call(ctl, "job.result", json_pack("{s:I}", "id", (json_int_t)id), &result);
	if (r)
		return r;
	if (out && (r = copy_files(ctl, id, json_object_get(result, "files"), out, quiet)))
		return r;
	if (report && (r = copy_file_to(ctl, id, json_object_get(result, "files"), "report",
					report, quiet)))
		return r;
	if (ctl->json)
		ctl_print_json(result);
	else
		print_summary(result);
	if (out && !ctl->json)
		printf("  Copied to %s\n", out);
	if (report && !ctl->json)
		printf("  Report written to %s\n", report);
	return EXIT_OK;
}
