/* SPDX-License-Identifier: GPL-3.0-or-later */
/* queue, instruments, drivers. */
#include <getopt.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asphctl.h"
#include "util-mem.h"

static void print_queue(const json_t *q)
{
	size_t i;
	json_t *job;

	printf("queue %s\n", json_is_true(json_object_get(q, "running")) ? "running" : "stopped");
	json_array_foreach(json_object_get(q, "jobs"), i, job)
		ctl_print_job_line(job);
}

int cmd_queue(struct ctl *ctl, int argc, char **argv)
{
	static const char usage[] = "queue [show | move JOB POSITION | start | stop [--abort]] [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	const char *method = "queue.get";
	json_t *params = NULL;
	bool abort_scans = false;
	int r = ctl_flag_option(ctl, argc, argv, "abort", 'a', &abort_scans, usage);
	int rest = argc - optind;
	char **args = argv + optind;

	if (r >= 0)
		return r;
	if (rest == 0 || (rest == 1 && !strcmp(args[0], "show"))) {
		method = "queue.get";
	} else if (rest == 3 && !strcmp(args[0], "move")) {
		int64_t id = ctl_job_id(args[1]);
		long long pos;
		if (id < 0 || ctl_parse_integer(args[2], 0, LLONG_MAX, &pos) < 0) {
			fprintf(stderr, "Usage: asphctl %s\n", usage);
			return EXIT_USAGE;
		}
		method = "queue.move";
		params = json_pack("{s:I, s:I}", "id", (json_int_t)id, "position", (json_int_t)pos);
	} else if (rest == 1 && !strcmp(args[0], "start")) {
		method = "queue.start";
	} else if (rest == 1 && !strcmp(args[0], "stop")) {
		method = "queue.stop";
		params = json_pack("{s:b}", "abort", abort_scans);
	} else {
		fprintf(stderr, "Usage: asphctl %s\n", usage);
		return EXIT_USAGE;
	}
	r = ctl_call(ctl, method, params, &result);
	if (r)
		return r;
	if (ctl->json)
		ctl_print_json(result);
	else
		print_queue(result);
	return EXIT_OK;
}

static void print_options(const json_t *opts)
{
	const char *key;
	json_t *v;

	json_object_foreach((json_t *)opts, key, v) {
		char *s = json_dumps(v, JSON_ENCODE_ANY | JSON_COMPACT);
		printf("      %-16s %s\n", key, s ? s : "?");
		free(s);
	}
}

int cmd_instruments(struct ctl *ctl, int argc, char **argv)
{
	static const char usage[] = "instruments [NAME] [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	int r = ctl_common_options(ctl, argc, argv, usage);
	size_t i;
	json_t *in;

	if (r >= 0)
		return r;
	if (argc - optind > 1) {
		fprintf(stderr, "Usage: asphctl %s\n", usage);
		return EXIT_USAGE;
	}
	if (argc - optind == 1)
		r = ctl_call(ctl, "instrument.status", json_pack("{s:s}", "name", argv[optind]),
			     &result);
	else
		r = ctl_call(ctl, "instrument.list", NULL, &result);
	if (r)
		return r;
	if (ctl->json) {
		ctl_print_json(result);
		return EXIT_OK;
	}
	json_t *list = json_object_get(result, "instruments");
	if (!list) {
		list = json_array();
		json_array_append(list, result);
	} else {
		json_incref(list);
	}
	json_array_foreach(list, i, in) {
		json_t *cfg = json_object_get(in, "configuration");
		printf("%s: %s", json_string_value(json_object_get(in, "name")),
		       json_string_value(json_object_get(in, "state")));
		if (json_is_integer(json_object_get(in, "job")))
			printf(", job %lld", (long long)json_integer_value(json_object_get(in, "job")));
		if (json_is_string(json_object_get(in, "fault")))
			printf(", last fault: %s", json_string_value(json_object_get(in, "fault")));
		if (json_is_object(json_object_get(in, "lock"))) {
			json_t *lock = json_object_get(in, "lock");
			printf(", locked by %s since %s%s: %s",
			       json_string_value(json_object_get(lock, "holder")),
			       json_string_value(json_object_get(lock, "since")),
			       json_is_true(json_object_get(lock, "pause")) ? " (pausing)" : "",
			       json_string_value(json_object_get(lock, "reason")));
		}
		printf("\n");
		for (const char *const *role = (const char *const[]){ "stage", "probe", NULL };
		     *role; role++) {
			json_t *r2 = json_object_get(cfg, *role);
			printf("  %s: %s %s\n", *role,
			       json_string_value(json_object_get(r2, "driver")),
			       json_string_value(json_object_get(r2, "version")));
			print_options(json_object_get(r2, "options"));
		}
	}
	json_decref(list);
	return EXIT_OK;
}

int cmd_drivers(struct ctl *ctl, int argc, char **argv)
{
	static const char usage[] = "drivers [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	int r = ctl_common_options(ctl, argc, argv, usage);
	size_t i, k;
	json_t *d, *o;

	if (r >= 0)
		return r;
	if (argc != optind) {
		fprintf(stderr, "Usage: asphctl %s\n", usage);
		return EXIT_USAGE;
	}
	r = ctl_call(ctl, "driver.list", NULL, &result);
	if (r)
		return r;
	if (ctl->json) {
		ctl_print_json(result);
		return EXIT_OK;
	}
	json_array_foreach(json_object_get(result, "drivers"), i, d) {
		printf("%s %s (%s): %s\n", json_string_value(json_object_get(d, "name")),
		       json_string_value(json_object_get(d, "version")),
		       json_string_value(json_object_get(d, "origin")),
		       json_string_value(json_object_get(d, "description")));
		json_array_foreach(json_object_get(d, "options"), k, o)
			printf("  %-16s %-7s default %-10s %s\n",
			       json_string_value(json_object_get(o, "name")),
			       json_string_value(json_object_get(o, "type")),
			       json_is_string(json_object_get(o, "default"))
				       ? json_string_value(json_object_get(o, "default")) : "-",
			       json_is_string(json_object_get(o, "help"))
				       ? json_string_value(json_object_get(o, "help")) : "");
	}
	return EXIT_OK;
}
