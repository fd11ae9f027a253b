/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asph scan: measures a plan with an instrument, offline, into a scan file. */
#include <getopt.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <jansson.h>

#include "acquire-tool.h"
#include "asph-tool.h"
#include "asph-engine/executor.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "plan-source.h"
#include "progress.h"
#include "util-mem.h"
#include "util-time.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_registry *, asph_registry_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_config *, asph_config_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_surface *, asph_surface_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_plan *, asph_plan_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_instrument *, asph_instrument_close)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scan *, asph_scan_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)

enum {
	OPT_INSTRUMENT = 0x2000, OPT_FORCE, OPT_RESUME, OPT_NO_STREAM, OPT_CLEARANCE,
	OPT_SKIP_OOR, OPT_PLUGIN_DIR, OPT_QUIET,
};

struct scan_args {
	struct plan_source ps;
	const char *lens, *instrument, *output, *plugin_dir;
	bool force, resume, no_stream, skip_oor, quiet;
	double clearance;
};

struct bar {
	bool tty, quiet;
	uint64_t last_ns;
};

static void progress_cb(const struct asph_scan_progress *p, void *data)
{
	struct bar *b = data;

	if (b->quiet)
		return;
	uint64_t t = now_monotonic_ns();
	bool final = p->state >= ASPH_SCAN_COMPLETED;
	double pct = p->total ? 100.0 * (double)p->done / (double)p->total : 100.0;
	char eta[32];

	progress_duration(p->eta_s, eta, sizeof(eta));
	if (b->tty) {
		int filled = (int)(pct / 100 * 30);
		fprintf(stderr, "\r[%-30.*s] %5.1f %% %llu/%llu  %.0f pt/s  ETA %s  %-9s%s",
			filled, "##############################", pct,
			(unsigned long long)p->done, (unsigned long long)p->total, p->rate, eta,
			asph_scan_state_name(p->state), final ? "\n" : "");
		return;
	}
	if (!final && t - b->last_ns < 1000000000u)
		return;
	b->last_ns = t;
	fprintf(stderr, "%s %llu/%llu points (%.1f %%), %.0f points/s, ETA %s\n",
		asph_scan_state_name(p->state), (unsigned long long)p->done,
		(unsigned long long)p->total, pct, p->rate, eta);
}

/* SIGINT and SIGTERM abort the scan from a thread of their own. */
struct sigwatch {
	sigset_t set;
	struct asph_scan *scan;
};

static void *sigwatch_run(void *data)
{
	struct sigwatch *sw = data;
	int sig;

	if (sigwait(&sw->set, &sig) == 0 && sig != SIGUSR2)
		asph_scan_abort(sw->scan);
	return NULL;
}

static int open_writer(const struct scan_args *a, const struct asph_surface *s,
		       const struct asph_plan *plan, const struct asph_instrument_config *ic,
		       struct asph_scanfile_writer **w, uint64_t *start,
		       struct asph_scanfile **recovered, struct asph_error *err)
{
	_cleanup_free_ char *pj = NULL, *plj = NULL, *ij = NULL;
	struct asph_scanfile_writer_options wo = { .flags = a->force ? ASPH_SCANFILE_OVERWRITE : 0 };

	*start = 0;
	if (a->resume)
		return asph_scan_reopen(a->output, plan, NULL, w, start, recovered, err);
	if (asph_prescription_to_json(asph_surface_prescription(s), &pj) < 0 ||
	    asph_plan_to_json(plan, &plj) < 0 || asph_instrument_config_to_json(ic, &ij) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	struct asph_scanfile_header_info info = { pj, plj, ij, NULL };
	return asph_scanfile_writer_create(a->output, &info, &wo, w, err);
}

static int run_scan(const struct scan_args *a, struct asph_instrument *inst,
		    const struct asph_surface *s, const struct asph_plan *plan,
		    struct asph_scanfile_writer *w, uint64_t start,
		    const struct asph_scanfile *recovered)
{
	struct bar bar = { .tty = isatty(STDERR_FILENO), .quiet = a->quiet };
	struct asph_scan_options so = {
		.flags = (a->no_stream ? 0 : ASPH_SCAN_STREAM) |
			 (a->skip_oor ? ASPH_SCAN_SKIP_OUT_OF_RANGE : 0),
		.start_index = start,
		.clearance = a->clearance,
		.progress = progress_cb,
		.progress_data = &bar,
		.recovered = recovered,
	};
	_cleanup_(asph_scan_freep) struct asph_scan *scan = NULL;
	struct sigwatch sw;
	struct asph_error err;
	pthread_t th;

	asph_error_clear(&err);
	if (asph_scan_new(inst, s, plan->xyz, plan->n, &so, &scan, &err) < 0) {
		asph_scanfile_writer_close(w, NULL);
		tool_print_error("scan", &err);
		return EXIT_FAILURE_RUN;
	}
	sigemptyset(&sw.set);
	sigaddset(&sw.set, SIGINT);
	sigaddset(&sw.set, SIGTERM);
	sigaddset(&sw.set, SIGUSR2);
	sw.scan = scan;
	pthread_sigmask(SIG_BLOCK, &sw.set, NULL);
	bool watching = pthread_create(&th, NULL, sigwatch_run, &sw) == 0;
	int r = asph_scan_run(scan, w, &err);
	if (watching) {
		pthread_kill(th, SIGUSR2);
		pthread_join(th, NULL);
	}
	pthread_sigmask(SIG_UNBLOCK, &sw.set, NULL);
	struct asph_scan_progress p;
	asph_scan_get_progress(scan, &p);
	if (r < 0) {
		tool_print_error(r == -ECANCELED ? "scan aborted" : "scan failed", &err);
		fprintf(stderr, "asph: %s keeps the %llu points measured before\n", a->output,
			(unsigned long long)p.done);
		return EXIT_FAILURE_RUN;
	}
	if (!a->quiet)
		printf("Scan completed: %llu points in %.2f s -> %s\n",
		       (unsigned long long)p.done, p.elapsed_s, a->output);
	return EXIT_OK;
}

static int scan(const struct scan_args *a)
{
	_cleanup_(asph_registry_freep) struct asph_registry *reg = NULL;
	_cleanup_(asph_config_freep) struct asph_config *cfg = NULL;
	_cleanup_(asph_surface_freep) struct asph_surface *s = NULL;
	_cleanup_(asph_plan_freep) struct asph_plan *plan = NULL;
	_cleanup_(asph_instrument_closep) struct asph_instrument *inst = NULL;
	struct asph_plan_options po = { .flags = ASPH_PLAN_NO_MESH };
	struct asph_scanfile_writer *w = NULL;
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *recovered = NULL;
	struct asph_error err;
	size_t idx = 0;
	uint64_t start = 0;

	asph_error_clear(&err);
	if (tool_load_surface(a->lens, &s) < 0 || tool_registry_new(a->plugin_dir, &reg) < 0)
		return EXIT_FAILURE_RUN;
	if (asph_config_resolve(reg, a->instrument, &cfg, &idx, &err) < 0) {
		tool_print_error("instrument", &err);
		return EXIT_USAGE;
	}
	_cleanup_free_ char *lens_json = NULL;
	if (asph_prescription_to_json(asph_surface_prescription(s), &lens_json) < 0 ||
	    asph_instrument_config_set_lens(&cfg->instruments[idx], lens_json, &err) < 0) {
		tool_print_error("instrument", &err);
		return EXIT_FAILURE_RUN;
	}
	if (plan_source_compute(&a->ps, s, &po, &plan, &err) < 0) {
		tool_print_error("plan", &err);
		return EXIT_FAILURE_RUN;
	}
	if (asph_instrument_open(&cfg->instruments[idx], 10000, &inst, &err) < 0) {
		tool_print_error("instrument", &err);
		return EXIT_FAILURE_RUN;
	}
	if (open_writer(a, s, plan, &cfg->instruments[idx], &w, &start, &recovered, &err) < 0) {
		tool_print_error(a->output, &err);
		return EXIT_FAILURE_RUN;
	}
	return run_scan(a, inst, s, plan, w, start, recovered);
}

static void usage(FILE *out)
{
	fprintf(out,
		"Usage: asph scan LENS --method M (--h H | --spacing MM | --points N)\n"
		"                 --instrument INSTRUMENT -o SCAN [OPTIONS]\n\n"
		"Measures the plan with an instrument and records every point in SCAN.\n"
		"LENS is a preset (weak, strong, turning-point) or a prescription file.\n");
	plan_method_help(out, "", "");
	fprintf(out,
		"  --h H | --spacing MM | --points N   the plan's density (exactly one)\n"
		PLAN_SOURCE_PROFILES_HELP
		"  --instrument I      a configuration file (FILE or FILE#NAME), or a driver\n"
		"                      spec NAME[:key=value,...], e.g. mock, mock:rate=20000\n"
		"  -o, --output SCAN   the scan file to write\n"
		"  --force             replace SCAN if it exists\n"
		"  --resume            continue the interrupted scan in SCAN after its last point\n"
		"  --no-stream         measure point by point even if the probe streams\n"
		"  --clearance MM      approach height above each point (default 0.5)\n"
		"  --skip-out-of-range record out-of-range readings and go on\n"
		"  --plugin-dir DIR    load driver plugins from DIR\n"
		"  --quiet             no progress (of the plan and of the scan)\n"
		"SIGINT or SIGTERM aborts the scan; the file keeps what was measured.\n");
}

static int take(int opt, const char *arg, void *data)
{
	struct scan_args *a = data;
	int r = plan_source_option(&a->ps, opt, arg);
	char *end;

	if (r <= 0)
		return r;
	switch (opt) {
	case OPT_INSTRUMENT: a->instrument = arg; break;
	case 'o': a->output = arg; break;
	case OPT_FORCE: a->force = true; break;
	case OPT_RESUME: a->resume = true; break;
	case OPT_NO_STREAM: a->no_stream = true; break;
	case OPT_SKIP_OOR: a->skip_oor = true; break;
	case OPT_PLUGIN_DIR: a->plugin_dir = arg; break;
	case OPT_QUIET: a->quiet = true; a->ps.quiet = 1; break;
	case OPT_CLEARANCE:
		a->clearance = strtod(arg, &end);
		if (*end || !(a->clearance > 0) || a->clearance > 1000) {
			fprintf(stderr, "asph scan: --clearance must be a length in mm, > 0\n");
			return -EINVAL;
		}
		break;
	}
	return 0;
}

static int parse(int argc, char **argv, struct scan_args *a)
{
	static const struct option long_opts[] = {
		PLAN_SOURCE_LONG_OPTIONS,
		{ "instrument", required_argument, NULL, OPT_INSTRUMENT },
		{ "output", required_argument, NULL, 'o' },
		{ "force", no_argument, NULL, OPT_FORCE },
		{ "resume", no_argument, NULL, OPT_RESUME },
		{ "no-stream", no_argument, NULL, OPT_NO_STREAM },
		{ "clearance", required_argument, NULL, OPT_CLEARANCE },
		{ "skip-out-of-range", no_argument, NULL, OPT_SKIP_OOR },
		{ "plugin-dir", required_argument, NULL, OPT_PLUGIN_DIR },
		{ "quiet", no_argument, NULL, OPT_QUIET },
		{ "help", no_argument, NULL, 'h' },
		{ NULL, 0, NULL, 0 },
	};
	int code = tool_getopt(argc, argv, "o:h", long_opts, usage, take, a);

	if (code >= 0)
		return code;
	if (optind + 1 != argc || !a->instrument || !a->output) {
		fprintf(stderr, "asph scan: give LENS, --instrument and -o SCAN (see --help)\n");
		return EXIT_USAGE;
	}
	a->lens = argv[optind];
	if (plan_source_finish(&a->ps, NULL) < 0)
		return EXIT_USAGE;
	if (a->resume && a->force) {
		fprintf(stderr, "asph scan: --resume and --force exclude each other\n");
		return EXIT_USAGE;
	}
	return -1;
}

int cmd_scan(int argc, char **argv)
{
	struct scan_args a = { 0 };
	int r = parse(argc, argv, &a);

	return r >= 0 ? r : scan(&a);
}
