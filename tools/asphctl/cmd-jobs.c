/* SPDX-License-Identifier: GPL-3.0-or-later */
/* submit, status, cancel, pause, resume, requeue, list, result. */
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "asphctl.h"
#include "util-fs.h"
#include "util-mem.h"

#define JSON_OPTION { "json", no_argument, NULL, 'j' }
#define HELP_OPTION { "help", no_argument, NULL, 'h' }

static int usage_error(const char *usage)
{
	fprintf(stderr, "Usage: asphctl %s\n", usage);
	return CTL_EXIT_USAGE;
}

static const char *str(const json_t *o, const char *key)
{
	const char *s = json_string_value(json_object_get(o, key));

	return s ? s : "-";
}

void ctl_print_job_line(const json_t *job)
{
	json_t *p = json_object_get(job, "progress");
	json_int_t done = json_integer_value(json_object_get(p, "done"));
	json_int_t total = json_integer_value(json_object_get(p, "total"));
	json_t *plan = json_object_get(job, "plan");
	char density[64];

	snprintf(density, sizeof(density), "%s %s=%g", str(plan, "method"), str(plan, "density"),
		 json_number_value(json_object_get(plan, "value")));
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
	printf("  plan        %s, %s = %g\n", str(json_object_get(job, "plan"), "method"),
	       str(json_object_get(job, "plan"), "density"),
	       json_number_value(json_object_get(json_object_get(job, "plan"), "value")));
	printf("  points      %lld of %lld\n",
	       (long long)json_integer_value(json_object_get(p, "done")),
	       (long long)json_integer_value(json_object_get(p, "total")));
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
		fprintf(stderr, "asphctl: %s:%d:%d: %s\n", lens, e.line, e.column, e.text);
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

static const char submit_usage[] =
	"submit LENS --method M (--h H | --spacing MM | --points N)\n"
	"       [--instrument NAME] [--priority P] [--label TEXT] [--dof LIST]\n"
	"       [--residual normal|sag] [--robust] [--zernike N]\n"
	"       [--part P] [--lot L] [--serial S] [--wait] [--json]";

int cmd_submit(struct ctl *ctl, int argc, char **argv)
{
	static const struct option opts[] = {
		{ "method", required_argument, NULL, 'm' },
		{ "h", required_argument, NULL, 'H' },
		{ "spacing", required_argument, NULL, 'S' },
		{ "points", required_argument, NULL, 'P' },
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
		{ "wait", no_argument, NULL, 'w' },
		JSON_OPTION, HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	_cleanup_(json_decrefp) json_t *params = json_object();
	_cleanup_(json_decrefp) json_t *result = NULL;
	json_t *plan = json_object(), *fit = json_object();
	bool wait = false;
	int c, r;

	json_object_set_new(params, "plan", plan);
	while ((c = getopt_long(argc, argv, "m:i:p:l:jh", opts, NULL)) != -1) {
		bool ok = true;
		switch (c) {
		case 'm': json_object_set_new(plan, "method", json_string(optarg)); break;
		case 'H': ok = set_real(plan, "h", optarg); break;
		case 'S': ok = set_real(plan, "spacing", optarg); break;
		case 'P': ok = set_real(plan, "points", optarg); break;
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
		case 'w': wait = true; break;
		case 'j': ctl->json = true; break;
		case 'h': printf("Usage: asphctl %s\n", submit_usage); json_decref(fit); return CTL_EXIT_OK;
		default: json_decref(fit); return usage_error(submit_usage);
		}
		if (!ok) {
			json_decref(fit);
			return CTL_EXIT_USAGE;
		}
	}
	if (optind + 1 != argc) {
		json_decref(fit);
		return usage_error(submit_usage);
	}
	if (json_object_size(fit))
		json_object_set_new(params, "fit", fit);
	else
		json_decref(fit);
	json_t *lens = lens_param(argv[optind]);
	if (!lens)
		return CTL_EXIT_ERROR;
	json_object_set_new(params, "lens", lens);
	r = ctl_call(ctl, "job.submit", json_incref(params), &result);
	if (r)
		return r;
	json_int_t id = json_integer_value(json_object_get(result, "id"));
	if (ctl->json && !wait)
		ctl_print_json(result);
	else if (!ctl->json)
		printf("job %lld queued (%lld points)\n", (long long)id,
		       (long long)json_integer_value(json_object_get(json_object_get(result, "progress"),
								     "total")));
	fflush(stdout);
	return wait ? ctl_watch_job(ctl, id, ctl->json) : CTL_EXIT_OK;
}

/* Commands that take JOB and [--json] and call one method. */
static int simple_job_command(struct ctl *ctl, int argc, char **argv, const char *method,
			      const char *usage, const char *done)
{
	static const struct option opts[] = { JSON_OPTION, HELP_OPTION, { NULL, 0, NULL, 0 } };
	_cleanup_(json_decrefp) json_t *result = NULL;
	int64_t id;
	int c, r;

	while ((c = getopt_long(argc, argv, "jh", opts, NULL)) != -1) {
		switch (c) {
		case 'j': ctl->json = true; break;
		case 'h': printf("Usage: asphctl %s\n", usage); return CTL_EXIT_OK;
		default: return usage_error(usage);
		}
	}
	if ((id = ctl_job_operand(argc, argv, usage)) < 0)
		return CTL_EXIT_USAGE;
	r = ctl_call(ctl, method, json_pack("{s:I}", "id", (json_int_t)id), &result);
	if (r)
		return r;
	if (ctl->json)
		ctl_print_json(result);
	else
		printf("job %lld %s (%s)\n", (long long)id, done, str(result, "state"));
	return CTL_EXIT_OK;
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
	static const struct option opts[] = {
		{ "restart", no_argument, NULL, 'r' }, JSON_OPTION, HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	static const char usage[] = "requeue JOB [--restart] [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	bool restart = false;
	int64_t id;
	int c, r;

	while ((c = getopt_long(argc, argv, "rjh", opts, NULL)) != -1) {
		switch (c) {
		case 'r': restart = true; break;
		case 'j': ctl->json = true; break;
		case 'h': printf("Usage: asphctl %s\n", usage); return CTL_EXIT_OK;
		default: return usage_error(usage);
		}
	}
	if ((id = ctl_job_operand(argc, argv, usage)) < 0)
		return CTL_EXIT_USAGE;
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
	return CTL_EXIT_OK;
}

int cmd_status(struct ctl *ctl, int argc, char **argv)
{
	static const struct option opts[] = {
		{ "history", no_argument, NULL, 'H' }, JSON_OPTION, HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	static const char usage[] = "status [JOB [--history]] [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	bool history = false;
	int c, r;

	while ((c = getopt_long(argc, argv, "jh", opts, NULL)) != -1) {
		switch (c) {
		case 'H': history = true; break;
		case 'j': ctl->json = true; break;
		case 'h': printf("Usage: asphctl %s\n", usage); return CTL_EXIT_OK;
		default: return usage_error(usage);
		}
	}
	if (optind + 1 == argc) {
		int64_t id = ctl_job_id(argv[optind]);
		if (id < 0)
			return CTL_EXIT_USAGE;
		r = ctl_call(ctl, "job.get", json_pack("{s:I, s:b}", "id", (json_int_t)id,
						       "history", history), &result);
		if (r)
			return r;
		if (ctl->json) {
			ctl_print_json(result);
			return CTL_EXIT_OK;
		}
		print_job(result);
		size_t i;
		json_t *h;
		json_array_foreach(json_object_get(result, "history"), i, h)
			printf("  %s  %-11s %-16s %s\n", str(h, "time"), str(h, "state"),
			       json_is_string(json_object_get(h, "actor")) ? str(h, "actor") : "-",
			       json_is_string(json_object_get(h, "reason")) ? str(h, "reason") : "");
		return CTL_EXIT_OK;
	}
	if (optind != argc)
		return usage_error(usage);
	r = ctl_call(ctl, "daemon.status", NULL, &result);
	if (r)
		return r;
	if (ctl->json) {
		ctl_print_json(result);
		return CTL_EXIT_OK;
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
	return CTL_EXIT_OK;
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
		JSON_OPTION, HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	static const char usage[] = "list [--state S[,S...]] [--instrument NAME] [--label TEXT]\n"
				    "       [--part P] [--lot L] [--serial S] [--mine] [--limit N]\n"
				    "       [--offset N] [--json]";
	_cleanup_(json_decrefp) json_t *params = json_object();
	_cleanup_(json_decrefp) json_t *result = NULL;
	int c, r;

	while ((c = getopt_long(argc, argv, "s:i:l:mn:o:jh", opts, NULL)) != -1) {
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
				return CTL_EXIT_USAGE;
			}
			json_object_set_new(params, c == 'n' ? "limit" : "offset", json_integer(v));
			break;
		}
		case 'j': ctl->json = true; break;
		case 'h': printf("Usage: asphctl %s\n", usage); return CTL_EXIT_OK;
		default: return usage_error(usage);
		}
	}
	if (optind != argc)
		return usage_error(usage);
	r = ctl_call(ctl, "job.list", json_incref(params), &result);
	if (r)
		return r;
	if (ctl->json) {
		ctl_print_json(result);
		return CTL_EXIT_OK;
	}
	size_t i;
	json_t *job;
	print_job_header();
	json_array_foreach(json_object_get(result, "jobs"), i, job)
		ctl_print_job_line(job);
	printf("(%zu of %lld)\n", json_array_size(json_object_get(result, "jobs")),
	       (long long)json_integer_value(json_object_get(result, "total")));
	return CTL_EXIT_OK;
}

/* One file of a job's result, fetched from the daemon chunk by chunk. */
struct fetch {
	struct ctl *ctl;
	int64_t id;
	const char *name;
	int code;               /* the exit code when a call failed */
};

static int fetch_chunks(FILE *f, void *data, struct asph_error *err)
{
	struct fetch *fe = data;
	json_int_t offset = 0;

	for (;;) {
		_cleanup_(json_decrefp) json_t *chunk = NULL;
		_cleanup_free_ void *bytes = NULL;
		const char *text;
		size_t n = 0;

		fe->code = ctl_call(fe->ctl, "job.file", json_pack("{s:I, s:s, s:I}", "id",
				    (json_int_t)fe->id, "name", fe->name, "offset", offset), &chunk);
		if (fe->code)
			return asph_error_set(err, -EIO, "%s: the daemon did not send it", fe->name);
		text = json_string_value(json_object_get(chunk, "data"));
		if (!text || proto_base64_decode(text, strlen(text), &bytes, &n) < 0)
			return asph_error_set(err, -EBADMSG, "%s: the daemon sent no base64", fe->name);
		if (n && fwrite(bytes, 1, n, f) != n)
			return asph_error_set(err, -errno, "%s: %s", fe->name, strerror(errno));
		offset += (json_int_t)n;
		if (json_is_true(json_object_get(chunk, "eof")) || n == 0)
			return 0;
	}
}

/*
 * Copies the files of job id's result into the directory out (created if
 * missing). The bytes come through the socket (job.file), so the caller
 * needs no access to the daemon's state directory. Each file is written
 * under a temporary name created exclusively in out and renamed into
 * place: a symlink planted in out is replaced, never written through.
 */
static int copy_files(struct ctl *ctl, int64_t id, const json_t *files, const char *out)
{
	_cleanup_close_ int dir = -1;
	const char *key;
	json_t *v;

	if (mkdir(out, 0777) < 0 && errno != EEXIST) {
		fprintf(stderr, "asphctl: %s: %s\n", out, strerror(errno));
		return CTL_EXIT_ERROR;
	}
	dir = open(out, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
	if (dir < 0) {
		fprintf(stderr, "asphctl: %s: %s\n", out, strerror(errno));
		return CTL_EXIT_ERROR;
	}
	json_object_foreach((json_t *)files, key, v) {
		struct fetch fe = { .ctl = ctl, .id = id, .name = json_string_value(v) };
		struct asph_error err;
		char buf[600];

		asph_error_clear(&err);
		if (!fe.name || fs_write_file_at(dir, fe.name, 0666, fetch_chunks, &fe, &err) < 0) {
			if (fe.code)
				return fe.code;
			fprintf(stderr, "asphctl: %s: %s\n", out,
				fe.name ? asph_error_format(&err, buf, sizeof(buf)) : "a file without a name");
			return CTL_EXIT_ERROR;
		}
	}
	return CTL_EXIT_OK;
}

static void print_summary(const json_t *res)
{
	json_t *s = json_object_get(res, "summary"), *dof, *unc, *v;
	json_t *prov = json_object_get(res, "provenance");
	const char *key;

	printf("job %lld: %lld points, %lld used\n",
	       (long long)json_integer_value(json_object_get(res, "job")),
	       (long long)json_integer_value(json_object_get(s, "n_points")),
	       (long long)json_integer_value(json_object_get(s, "n_used")));
	printf("  form error  RMS %.2f nm, PV %.2f nm, PVr %.2f nm\n",
	       json_number_value(json_object_get(s, "rms_nm")),
	       json_number_value(json_object_get(s, "pv_nm")),
	       json_number_value(json_object_get(s, "pvr_nm")));
	dof = json_object_get(s, "dof");
	unc = json_object_get(s, "uncertainty");
	json_object_foreach(dof, key, v) {
		/* mm and rad inside; um and urad for people. R and k as they are. */
		bool angle = key[0] == 'r' && key[1] && !key[2];
		bool shift = key[0] == 't' && key[1] && !key[2];
		double scale = angle || shift ? (angle ? 1e6 : 1e3) : 1;
		printf("  %-3s %14.4f +- %.4f %s\n", key, json_number_value(v) * scale,
		       json_number_value(json_object_get(unc, key)) * scale,
		       angle ? "urad" : shift ? "um" : key[0] == 'R' ? "mm" : "");
	}
	printf("  scan sha256 %s\n", str(json_object_get(prov, "scan"), "sha256"));
	printf("  files in %s\n", str(res, "dir"));
}

int cmd_result(struct ctl *ctl, int argc, char **argv)
{
	static const struct option opts[] = {
		{ "out", required_argument, NULL, 'o' }, JSON_OPTION, HELP_OPTION,
		{ NULL, 0, NULL, 0 },
	};
	static const char usage[] = "result JOB [--out DIR] [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	const char *out = NULL;
	int64_t id;
	int c, r;

	while ((c = getopt_long(argc, argv, "o:jh", opts, NULL)) != -1) {
		switch (c) {
		case 'o': out = optarg; break;
		case 'j': ctl->json = true; break;
		case 'h': printf("Usage: asphctl %s\n", usage); return CTL_EXIT_OK;
		default: return usage_error(usage);
		}
	}
	if ((id = ctl_job_operand(argc, argv, usage)) < 0)
		return CTL_EXIT_USAGE;
	r = ctl_call(ctl, "job.result", json_pack("{s:I}", "id", (json_int_t)id), &result);
	if (r)
		return r;
	if (out && (r = copy_files(ctl, id, json_object_get(result, "files"), out)))
		return r;
	if (ctl->json)
		ctl_print_json(result);
	else
		print_summary(result);
	if (out && !ctl->json)
		printf("  copied to %s\n", out);
	return CTL_EXIT_OK;
}
