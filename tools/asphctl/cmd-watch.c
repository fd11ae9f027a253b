/* SPDX-License-Identifier: GPL-3.0-or-later */
/* watch: a live progress bar on a terminal, plain lines otherwise. */
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "asphctl.h"
#include "progress.h"
#include "util-mem.h"

#define BAR_WIDTH 30

struct view {
	int64_t id;
	bool tty, quiet;        /* quiet: --json, the job's JSON at the end only */
	bool progress;          /* not --quiet: the progress bar or lines */
	int last_percent;
	bool last_mc;           /* the last progress counted trials */
	bool last_planning;     /* the last progress was the plan's search */
	bool bar_drawn;
};

/* The progress of a job.progress event: plan points while measuring,
 * trials during its Monte Carlo uncertainty (phase "uncertainty"), the
 * search's characterizations while the plan for the tolerance is chosen
 * (phase "planning"). */
static void show_progress(struct view *v, const json_t *p)
{
	const json_t *trials = json_object_get(p, "trials");
	bool mc = json_is_object(trials);
	const json_t *src = mc ? trials : p;
	json_int_t done = json_integer_value(json_object_get(src, "done"));
	json_int_t total = json_integer_value(json_object_get(src, mc ? "planned" : "total"));
	double rate = json_number_value(json_object_get(src, "rate"));
	double frac = total > 0 ? (double)done / (double)total : 0;
	int percent = (int)(100 * frac);
	const char *phase = json_string_value(json_object_get(p, "phase"));
	bool planning = !mc && phase && !strcmp(phase, "planning");
	const char *unit = mc ? "trials" : planning ? "characterizations" : "points";
	const char *what = mc ? "uncertainty " : planning ? "plan search " : "";
	char eta_text[32];

	if (v->quiet || !v->progress)
		return;
	progress_duration(json_is_number(json_object_get(p, "eta_s"))
				  ? json_number_value(json_object_get(p, "eta_s")) : NAN,
			  eta_text, sizeof(eta_text));
	if (v->tty) {
		char bar[BAR_WIDTH + 1];
		int fill = (int)(frac * BAR_WIDTH);
		for (int i = 0; i < BAR_WIDTH; i++)
			bar[i] = i < fill ? '#' : '.';
		bar[BAR_WIDTH] = '\0';
		printf("\r\033[Kjob %lld %s[%s] %5.1f %%  %lld/%lld  %.1f %s/s  ETA %s",
		       (long long)v->id, what, bar, 100 * frac, (long long)done,
		       (long long)total, rate, mc ? "trials" : planning ? "char" : "pt", eta_text);
		v->bar_drawn = true;
	} else if (percent != v->last_percent || mc != v->last_mc ||
		   planning != v->last_planning) {
		printf("job %lld: %s%lld/%lld %s (%d %%), %.1f %s/s, ETA %s\n", (long long)v->id,
		       what, (long long)done, (long long)total, unit, percent, rate, unit,
		       eta_text);
	}
	v->last_percent = percent;
	v->last_mc = mc;
	v->last_planning = planning;
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

/* A completed job exits as asph fit does on its verdict (exit-codes.h). */
static int verdict_exit(const char *state, const char *verdict)
{
	if (!state || strcmp(state, "completed"))
		return EXIT_JOB_FAILED;
	if (verdict && !strcmp(verdict, "fail"))
		return EXIT_VERDICT_FAIL;
	if (verdict && !strcmp(verdict, "undecided"))
		return EXIT_VERDICT_UNDECIDED;
	return EXIT_OK;
}

static int finish(struct ctl *ctl, struct view *v)
{
	_cleanup_(json_decrefp) json_t *job = NULL;
	int r = ctl_call(ctl, "job.get", json_pack("{s:I}", "id", (json_int_t)v->id), &job);

	if (r)
		return r;
	const char *verdict = json_string_value(json_object_get(job, "verdict"));

	if (ctl->json)
		ctl_print_json(job);
	else if (!v->quiet && verdict)
		printf("job %lld: verdict %s\n", (long long)v->id, verdict);
	return verdict_exit(json_string_value(json_object_get(job, "state")), verdict);
}

int ctl_watch_job(struct ctl *ctl, int64_t id, bool progress)
{
	struct view v = { .id = id, .tty = isatty(STDOUT_FILENO), .quiet = ctl->json,
			  .progress = progress,
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
			show_progress(&v, p);
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
	static const char usage[] = "watch JOB [--quiet] [--json]";
	bool quiet = false;
	int64_t id;
	int c;

	if ((c = ctl_flag_option(ctl, argc, argv, "quiet", 'q', &quiet, usage)) >= 0)
		return c;
	if ((id = ctl_job_operand(argc, argv, usage)) < 0)
		return EXIT_USAGE;
	return ctl_watch_job(ctl, id, !quiet);
}
