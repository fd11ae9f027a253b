/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asph synth: the plan points of a part as they would be measured. */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph/fit.h"
#include "asph/points.h"
#include "asph/zernike.h"
#include "asph-tool.h"
#include "plan-source.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_surface *, asph_surface_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)

enum {
	OPT_SHIFT = 0x100,
	OPT_TILT,
	OPT_CLOCKING,
	OPT_ZERNIKE,
	OPT_NOISE,
	OPT_SEED,
};

#define MAX_TERMS 64

struct synth_cli {
	struct plan_source src;
	struct asph_synth_options so;
	struct asph_synth_term terms[MAX_TERMS];
	const char *out;
};

static void usage(FILE *out)
{
	fprintf(out,
		"Usage: asph synth LENS --method M (--h H | --spacing MM | --points N) [OPTIONS]\n\n"
		"Test data: the points of a sampling plan as a part with the given misalignment,\n"
		"form error and noise would be measured. The part's surface is the nominal one\n"
		"plus the form error along its normal; noise is added along the normal too; the\n"
		"part is then moved: p = Ry(ry) Rx(rx) Rz(rz) q + (x, y, z)\n"
		"(docs/characterization.md). asph fit LENS on the output reports the shift,\n"
		"tilt and clocking back.\n\n");
	plan_method_help(out, "", "");
	fprintf(out,
		PLAN_DENSITY_HELP
		"  --shift X,Y,Z       shift of the part, mm (default 0,0,0)\n"
		"  --tilt RX,RY        tilt about the machine x then y axis, rad (default 0,0)\n"
		"  --clocking RZ       rotation about the part's own axis, applied first, rad\n"
		"                      (default 0; a rotationally symmetric part shows it only\n"
		"                      through its form error)\n"
		"  --zernike J=NM,...  form error: Noll index = coefficient in nm over r / a\n"
		"  --noise NM          Gaussian noise, standard deviation in nm (default 0)\n"
		"  --seed S            random seed (default 1); same seed, same points\n"
		"  -o, --output OUT    .csv (default '-': CSV on stdout), .ply or .json\n"
		PLAN_SOURCE_QUIET_HELP
		"  -h, --help          this text\n");
}

static int parse_number(const char *s, char **end, double *out)
{
	errno = 0;
	*out = strtod(s, end);
	return errno || *end == s || !isfinite(*out) ? -1 : 0;
}

/* Exactly n comma-separated numbers. */
static int parse_list(const char *arg, const char *name, double *v, int n)
{
	const char *p = arg;
	char *end;

	for (int i = 0; i < n; i++) {
		if (parse_number(p, &end, &v[i]) < 0 || *end != (i + 1 < n ? ',' : '\0')) {
			fprintf(stderr, "asph synth: --%s: '%s' is not %d comma-separated numbers\n",
				name, arg, n);
			return -1;
		}
		p = end + 1;
	}
	return 0;
}

static int parse_terms(struct synth_cli *c, const char *arg)
{
	const char *p = arg;
	char *end;

	c->so.n_terms = 0;
	while (*p) {
		long j;
		double nm;

		errno = 0;
		j = strtol(p, &end, 10);
		if (errno || end == p || *end != '=' || j < 1 || j > ASPH_ZERNIKE_MAX_J ||
		    parse_number(end + 1, &end, &nm) < 0 || (*end != ',' && *end != '\0') ||
		    c->so.n_terms == MAX_TERMS) {
			fprintf(stderr, "asph synth: --zernike: bad term at '%s' (J=NM with J in 1..%d, "
					"at most %d terms)\n", p, ASPH_ZERNIKE_MAX_J, MAX_TERMS);
			return -1;
		}
		c->terms[c->so.n_terms++] = (struct asph_synth_term){ (int)j, nm };
		p = *end ? end + 1 : end;
	}
	c->so.terms = c->terms;
	return 0;
}

static int take_option(int opt, const char *arg, void *data)
{
	struct synth_cli *c = data;
	double v[3];
	char *end;

	switch (opt) {
	case OPT_SHIFT:
		if (parse_list(arg, "shift", v, 3) < 0)
			return -1;
		memcpy(c->so.pose.t, v, sizeof(c->so.pose.t));
		return 0;
	case OPT_TILT:
		if (parse_list(arg, "tilt", v, 2) < 0)
			return -1;
		c->so.pose.rx = v[0];
		c->so.pose.ry = v[1];
		return 0;
	case OPT_CLOCKING:
		if (parse_list(arg, "clocking", v, 1) < 0)
			return -1;
		c->so.pose.rz = v[0];
		return 0;
	case OPT_ZERNIKE:
		return parse_terms(c, arg);
	case OPT_NOISE:
		if (parse_number(arg, &end, &v[0]) < 0 || *end || v[0] < 0) {
			fprintf(stderr, "asph synth: --noise: '%s' is not a number >= 0\n", arg);
			return -1;
		}
		c->so.noise_nm = v[0];
		return 0;
	case OPT_SEED:
		errno = 0;
		c->so.seed = strtoul(arg, &end, 10);
		if (errno || end == arg || *end || arg[0] == '-') {
			fprintf(stderr, "asph synth: --seed: '%s' is not a whole number >= 0\n", arg);
			return -1;
		}
		return 0;
	case 'o':
		c->out = arg;
		return 0;
	default:
		return plan_source_option(&c->src, opt, arg) == 0 ? 0 : -1;
	}
}

/* EXIT_OK, the exit code to leave with, or -1 after --help. */
static int parse_args(struct synth_cli *c, int argc, char **argv, const char **lens)
{
	static const struct option longopts[] = {
		PLAN_SOURCE_LONG_OPTIONS,
		{ "shift", required_argument, NULL, OPT_SHIFT },
		{ "tilt", required_argument, NULL, OPT_TILT },
		{ "clocking", required_argument, NULL, OPT_CLOCKING },
		{ "zernike", required_argument, NULL, OPT_ZERNIKE },
		{ "noise", required_argument, NULL, OPT_NOISE },
		{ "seed", required_argument, NULL, OPT_SEED },
		{ "output", required_argument, NULL, 'o' },
		PLAN_SOURCE_QUIET_OPTION,
		{ "help", no_argument, NULL, 'h' },
		{ NULL, 0, NULL, 0 },
	};
	int r = tool_getopt(argc, argv, "ho:", longopts, usage, take_option, c);

	if (r >= 0)
		return r == EXIT_OK ? -1 : r;
	if (argc - optind != 1) {
		fprintf(stderr, "asph synth: need exactly one LENS (see --help)\n");
		return EXIT_USAGE;
	}
	*lens = argv[optind];
	if (!c->src.have_method) {
		fprintf(stderr, "asph synth: --method is required (see --help)\n");
		return EXIT_USAGE;
	}
	return plan_source_finish(&c->src, NULL) < 0 ? EXIT_USAGE : EXIT_OK;
}

int cmd_synth(int argc, char **argv)
{
	_cleanup_(asph_surface_freep) struct asph_surface *s = NULL;
	_cleanup_(asph_points_freep) struct asph_points *pts = NULL;
	struct synth_cli c = { .out = "-", .so.seed = 1 };
	struct asph_error err;
	const char *lens = NULL;
	int r = parse_args(&c, argc, argv, &lens);

	if (r != EXIT_OK)
		return r < 0 ? EXIT_OK : r;
	if (tool_load_surface(lens, &s) < 0)
		return EXIT_FAILURE_RUN;
	if (plan_source_load(&c.src, s, &pts) < 0)
		return EXIT_FAILURE_RUN;
	asph_error_clear(&err);
	if (asph_fit_synthesize(s, pts->xyz, pts->n, &c.so, pts->xyz, &err) < 0 ||
	    asph_points_write(c.out, pts, NULL, &err) < 0) {
		tool_print_error("synth", &err);
		return EXIT_FAILURE_RUN;
	}
	return EXIT_OK;
}
