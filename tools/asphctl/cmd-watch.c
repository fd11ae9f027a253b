/* SPDX-License-Identifier: GPL-3.0-or-later */
/* watch: a live progress bar on a terminal, plain lines otherwise. */
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "asphctl.h"
#include "util-mem.h"

#define BAR_WIDTH 30

struct view {
	int64_t id;
	bool tty, quiet;
	int last_percent;
	bool bar_drawn;
};

static void format_eta(double s, char *buf, size_t size)
{
	if (!(s >= 0) || !isfinite(s))
		snprintf(buf, size, "--:--");
	else if (s < 3600)
		snprintf(buf, size, "%d:%02d", (int)s / 60, (int)s % 60);
	else
		snprintf(buf, size, "%d:%02d:%02d", (int)s / 3600, (int)s / 60 % 60, (int)s % 60);
}

static void show_progress(struct view *v, json_int_t done, json_int_t total, double rate,
			  double eta)
{
	double frac = total > 0 ? (double)done / (double)total : 0;
	int percent = (int)(100 * frac);
	char eta_text[32];

	if (v->quiet)
		return;
	format_eta(eta, eta_text, sizeof(eta_text));
	if (v->tty) {
		char bar[BAR_WIDTH + 1];
		int fill = (int)(frac * BAR_WIDTH);
		for (int i = 0; i < BAR_WIDTH; i++)
			bar[i] = i < fill ? '#' : '.';
		bar[BAR_WIDTH] = '\0';
		printf("\r\033[Kjob %lld [%s] %5.1f %%  %lld/%lld  %.1f pt/s  ETA %s",
		       (long long)v->id, bar, 100 * frac, (long long)done, (long long)total, rate,
		       eta_text);
		v->bar_drawn = true;
	} else if (percent != v->last_percent) {
		printf("job %lld: %lld/%lld points (%d %%), %.1f points/s, ETA %s\n",
		       (long long)v->id, (long long)done, (long long)total, percent, rate, eta_text);
	}
	v->last_percent = percent;
	fflush(stdout);
}

static void show_state(struct view *v, const char *state, const char *reason)
{
	if (v->quiet)
		return;
	if (v->bar_drawn) {
		printf("\n");
		v->bar_drawn = false;
	}
	printf("job %lld: %s%s%s\n", (long long)v->id, state, reason ? ": " : "",
	       reason ? reason : "");
	fflush(stdout);
}

static bool ended(const char *state)
{
	return !strcmp(state, "completed") || !strcmp(state, "failed") ||
	       !strcmp(state, "cancelled") || !strcmp(state, "interrupted");
}

static int finish(struct ctl *ctl, struct view *v)
{
	_cleanup_(json_decrefp) json_t *job = NULL;
	int r = ctl_call(ctl, "job.get", json_pack("{s:I}", "id", (json_int_t)v->id), &job);

	if (r)
		return r;
	if (ctl->json)
		ctl_print_json(job);
	else if (!v->quiet && json_is_string(json_object_get(job, "verdict")))
		printf("job %lld: verdict %s\n", (long long)v->id,
		       json_string_value(json_object_get(job, "verdict")));
	return strcmp(json_string_value(json_object_get(job, "state")), "completed")
		? CTL_EXIT_JOB_FAILED : CTL_EXIT_OK;
}

int ctl_watch_job(struct ctl *ctl, int64_t id, bool quiet)
{
	struct view v = { .id = id, .tty = isatty(STDOUT_FILENO), .quiet = quiet,
			  .last_percent = -1 };
	_cleanup_(json_decrefp) json_t *sub = NULL;
	_cleanup_(json_decrefp) json_t *job = NULL;
	const char *state;
	int r;

	/* Subscribe first, then read the state: no change can fall between. */
	r = ctl_call(ctl, "events.subscribe",
		     json_pack("{s:[s,s], s:I}", "events", "job", "progress", "job", (json_int_t)id),
		     &sub);
	if (r)
		return r;
	r = ctl_call(ctl, "job.get", json_pack("{s:I}", "id", (json_int_t)id), &job);
	if (r)
		return r;
	state = json_string_value(json_object_get(job, "state"));
	show_state(&v, state, NULL);
	if (ended(state))
		return finish(ctl, &v);
	for (;;) {
		_cleanup_(json_decrefp) json_t *ev = NULL;
		r = conn_next_event(ctl->conn, -1, &ev);
		if (r < 0) {
			struct ctl_error e = { .code = 0 };
			snprintf(e.message, sizeof(e.message), "the connection to asphd broke");
			return ctl_fail(&e);
		}
		if (!ctl->json)
			ctl_escape_json(ev);
		const char *method = json_string_value(json_object_get(ev, "method"));
		json_t *p = json_object_get(ev, "params");
		if (json_integer_value(json_object_get(p, "job")) != id)
			continue;
		if (!strcmp(method, "job.progress")) {
			show_progress(&v, json_integer_value(json_object_get(p, "done")),
				      json_integer_value(json_object_get(p, "total")),
				      json_number_value(json_object_get(p, "rate")),
				      json_number_value(json_object_get(p, "eta_s")));
		} else if (!strcmp(method, "job.state")) {
			state = json_string_value(json_object_get(p, "state"));
			show_state(&v, state, json_string_value(json_object_get(p, "reason")));
			if (state && ended(state))
				return finish(ctl, &v);
		}
	}
}

int cmd_watch(struct ctl *ctl, int argc, char **argv)
{
	static const char usage[] = "watch JOB [--json]";
	int64_t id;
	int c;

	if ((c = ctl_common_options(ctl, argc, argv, usage)) >= 0)
		return c;
	if ((id = ctl_job_operand(argc, argv, usage)) < 0)
		return CTL_EXIT_USAGE;
	return ctl_watch_job(ctl, id, ctl->json);
}
