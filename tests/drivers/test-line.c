/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The line driver: its profile parser and reply decoder against
 * hand-computed cases, the built-in profiles, and each profile against a
 * simulator written from the same vendor reference (line-sim.c), over TCP
 * on 127.0.0.1 and over a pseudo-terminal: a whole scan of the strong
 * preset whose fit recovers the part's misalignment, and the faults (a
 * device error, a garbled line, a stall, a disconnect in the middle of a
 * move, a wrong axis id), each ending with its reason, a readable scan
 * file and the stage stopped.
 */
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "asph-engine/executor.h"
#include "asph/fit.h"
#include "line-sim.h"
#include "line/files.h"
#include "line/profile.h"
#include "line/protocol.h"
#include "mock/protocol.h"
#include "scan-fixture.h"
#include "util-time.h"

/* The part's misalignment: what the fit must recover. */
#define SHIFT_X 0.0371
#define SHIFT_Y -0.0213
#define SHIFT_Z 0.0119
#define TILT_X 231.7e-6
#define TILT_Y -148.3e-6
#define MISALIGNMENT "\"shift_x\": 0.0371, \"shift_y\": -0.0213, \"shift_z\": 0.0119, " \
	"\"tilt_x\": 231.7, \"tilt_y\": -148.3"

/* ---------------------------------------------------------- parser */

static int parse(const char *text, struct line_profile *p, struct asph_error *err)
{
	return line_profile_parse(text, strlen(text), "lab.profile", p, err);
}

#define HEAD "asphd-line-profile 1\nname lab\nrole probe\nsend_terminator \"\\r\"\n" \
	"reply_terminator \"\\r\"\n"

static void test_profile_refusals(void **state)
{
	static const struct {
		const char *text;
		int line, column;
		const char *words;
	} cases[] = {
		{ "", 1, 1, "the first line must be 'asphd-line-profile 1'" },
		{ "asphd-line-profile 2\n", 1, 1, "the first line must be" },
		{ HEAD "colour blue\n", 6, 1, "unknown keyword 'colour'" },
		{ HEAD "op read\n  query \"M1\" \"M1,{valeu}\"\nend\n", 7, 18, "unknown placeholder" },
		{ HEAD "op read\n  query \"M{target}\" \"M1,{value}\"\nend\n", 7, 0, "" },
		{ HEAD "op read\n  query \"M1\" \"M1,{value}\n", 7, 14, "a string without its closing quote" },
		{ HEAD "op read\n  query \"M1\" \"M1,{value}\"\n", 6, 1, "the operation 'read' has no 'end'" },
		{ HEAD "op read\n  query \"M1\" \"M1,{code}\"\nend\n", 6, 1, "need {value}" },
		{ HEAD "op read\n  jump 3\nend\n", 7, 3, "'jump' is not a step" },
		{ HEAD "op fly\nend\n", 6, 4, "'fly' is not an operation" },
		{ HEAD "serial 9600 9 none 1\n", 6, 13, "9 is outside 5 .. 8" },
		{ HEAD "serial 9600 8 mark 1\n", 6, 15, "parity 'mark'" },
		{ HEAD "serial 9600.5 8 none 1\n", 6, 8, "'9600.5' is not a whole number" },
		{ HEAD "tcp_port m\n", 6, 10, "'m' is not a number" },
		{ HEAD "decimals 1e99\n", 6, 10, "1e99 is outside 0 .. 12" },
		{ HEAD "send_terminator \"\\q\"\n", 6, 17, "not a terminator" },
		{ HEAD "error 7 \"a\"\nerror 7 \"b\"\n", 7, 7, "error code 7 listed twice" },
		{ HEAD "op read\n  check\nend\n", 7, 3, "'check' needs an error_query" },
		{ HEAD "op read\n  query \"M1\" \"{*}{text}\"\nend\n", 7, 18, "two wildcards" },
		{ "asphd-line-profile 1\nname Lab\n", 2, 6, "name 'Lab'" },
		{ "asphd-line-profile 1\nname lab\nrole stage\nsend_terminator \"\\n\"\n"
		  "reply_terminator \"\\n\"\nop position\n  query \"P\" \"{p0}\"\nend\n", 0, 0,
		  "a stage profile needs the operation 'home'" },
		{ HEAD "description \"caf\xc3\xa9\"\n", 6, 17, "not ASCII text" },
	};
	struct line_profile p;
	struct asph_error err;

	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		asph_error_clear(&err);
		int r = parse(cases[i].text, &p, &err);
		if (i == 4) {
			/* {target} in a probe's query: a command placeholder is fine there */
			if (r < 0)
				fail_msg("case %zu: %s", i, err.message);
			continue;
		}
		if (r != -EINVAL || !strstr(err.message, cases[i].words) ||
		    strcmp(err.source, "lab.profile") || err.line != cases[i].line ||
		    (cases[i].column && err.column != cases[i].column))
			fail_msg("case %zu: %d %s:%d:%d %s", i, r, err.source, err.line, err.column,
				 err.message);
	}
}

/* Every built-in profile is compiled in, loads by its name with no
 * profile directory anywhere, and has what its role needs; a name that
 * is none is refused with the built-in ones named. */
static void test_builtin_profiles(void **state)
{
	static const char *const names[] = {
		"pi-gcs", "newport-esp", "aerotech-ascii", "linuxcnc", "keyence-lk", "mitutoyo-vcp",
		"sylvac",
	};
	struct line_profile p;
	struct asph_error err;

	assert_null(getenv("ASPH_LINE_PROFILE_PATH"));
	assert_int_equal(line_builtin_profiles_count, sizeof(names) / sizeof(names[0]));
	for (size_t i = 0; i < sizeof(names) / sizeof(names[0]); i++) {
		asph_error_clear(&err);
		if (line_profile_load(names[i], &p, &err) < 0)
			fail_msg("%s: %s:%d:%d: %s", names[i], err.source, err.line, err.column,
				 err.message);
		assert_string_equal(p.name, names[i]);
		assert_true(p.reference[0] && p.description[0]);
	}
	asph_error_clear(&err);
	assert_int_equal(line_profile_load("pi-gsc", &p, &err), -ENOENT);
	assert_non_null(strstr(err.message, "no line profile 'pi-gsc'"));
	assert_non_null(strstr(err.message, "built in: aerotech-ascii, keyence-lk, "));
}

/* ----------------------------------------------------- the decoder */

static void test_reader(void **state)
{
	struct line_reader r = { .len = 0 };
	char out[LINE_REPLY_MAX];
	struct asph_error err;

	/* GCS: continued lines end with a space before LF */
	const char gcs[] = "1=0.5000000 \n2=-1.2500000 \n3=3.0000000\n1=";
	assert_int_equal(line_reader_add(&r, gcs, sizeof(gcs) - 1, &err), 0);
	assert_int_equal(line_reader_take(&r, "\n", " ", out, sizeof(out), &err), 1);
	assert_string_equal(out, "1=0.5000000\n2=-1.2500000\n3=3.0000000");
	assert_int_equal(line_reader_take(&r, "\n", " ", out, sizeof(out), &err), 0);
	line_reader_pending(&r, out, sizeof(out));
	assert_string_equal(out, "1=");
	/* a line with control bytes is garbled, and is consumed */
	line_reader_clear(&r);
	assert_int_equal(line_reader_add(&r, "M1,\x02+0.1\r", 9, &err), 0);
	assert_int_equal(line_reader_take(&r, "\r", "", out, sizeof(out), &err), -EPROTO);
	assert_non_null(strstr(err.message, "garbled reply 'M1,\\x02+0.1'"));
	assert_int_equal(r.len, 0);
	/* two-byte terminators */
	assert_int_equal(line_reader_add(&r, "ABS_ACT_POS X 1.5\r\nrest", 23, &err), 0);
	assert_int_equal(line_reader_take(&r, "\r\n", "", out, sizeof(out), &err), 1);
	assert_string_equal(out, "ABS_ACT_POS X 1.5");
}

static void test_patterns(void **state)
{
	struct line_vars v = { .axis_ids = { "1", "2", "3" }, .axis = 1, .decimals = 4,
			       .target = { 1.5, -0.25, 12 }, .speed = 7 };
	struct line_match m;
	char out[128];
	bool per_axis;
	struct asph_error err;

	memset(&m, 0, sizeof(m));
	assert_true(line_match("{axis}={pos}", "2=-1.2500000", &v, &m));
	assert_true(m.has_pos[1] && m.pos[1] == -1.25 && !m.has_pos[0]);
	assert_false(line_match("{axis}={pos}", "1=-1.2500000", &v, &m));      /* another axis */
	assert_false(line_match("{axis}={pos}", "2=-1.25x", &v, &m));
	assert_false(line_match("{axis}={pos}", "2=", &v, &m));
	assert_true(line_match("{a0}={p0}\n{a1}={p1}\n{a2}={p2}", "1=1e-3\n2=+.5\n3=7.", &v, &m));
	assert_true(m.pos[0] == 1e-3 && m.pos[1] == 0.5 && m.pos[2] == 7);
	assert_true(line_match("ER,{*},{code}", "ER,M1,22", &v, &m) && m.code == 22);
	assert_true(line_match("E{code} {text}", "E32 Timeout", &v, &m));
	assert_string_equal(m.text, "Timeout");
	assert_true(line_match("{hex}", "1F", &v, &m) && m.code == 31);
	assert_true(line_match("\\xB1", "\xb1", &v, &m));
	assert_true(line_match("01A{value}", "01A-0001.23450", &v, &m) && m.value == -1.2345);
	assert_int_equal(line_expand("MOV {axis} {target} {a2} {t2} VEL {speed}", &v, out,
				     sizeof(out), &err), 0);
	assert_string_equal(out, "MOV 2 -0.2500 3 12.0000 VEL 7.0000");
	v.target[1] = -0.00001;
	assert_int_equal(line_expand("{target}", &v, out, sizeof(out), &err), 0);
	assert_string_equal(out, "0.0000");     /* no negative zero */
	v.target[1] = NAN;
	assert_int_equal(line_expand("{target}", &v, out, sizeof(out), &err), -EINVAL);
	assert_int_equal(line_text_check("{pos}", LINE_TEXT_COMMAND, &per_axis, &err), -EINVAL);
	assert_int_equal(line_text_check("POS? {axis}", LINE_TEXT_COMMAND, &per_axis, &err), 0);
	assert_true(per_axis);
}

/* --------------------------------------------------------- benches */

struct env {
	struct scan_fixture fx;
	struct asph_plan *plan;         /* the plan scanned: fx's, or dense */
	struct asph_plan *dense;
	struct mock_part *part;
};

static const struct mock_part_params part_params = {
	.lens = "strong",
	.pose = { .t = { SHIFT_X, SHIFT_Y, SHIFT_Z }, .rx = TILT_X, .ry = TILT_Y },
	.seed = 1,
};

/* Where the mock stage that carries a sensor is: the mock stage's
 * operations wrapped to tell (the executor calls them from one thread,
 * the simulator reads from its own). */
static pthread_mutex_t tracked_lock = PTHREAD_MUTEX_INITIALIZER;
static double tracked[3];
static const struct asph_stage_ops *mock_stage;

static void track(struct asph_device *d)
{
	double p[3];

	if (mock_stage->position(d, p, 0, NULL) < 0)
		return;
	pthread_mutex_lock(&tracked_lock);
	memcpy(tracked, p, sizeof(p));
	pthread_mutex_unlock(&tracked_lock);
}

static int track_home(struct asph_device *d, unsigned t, struct asph_error *err)
{
	int r = mock_stage->home(d, t, err);
	track(d);
	return r;
}

static int track_move(struct asph_device *d, const double *p, unsigned t, struct asph_error *err)
{
	int r = mock_stage->move_to(d, p, t, err);
	track(d);
	return r;
}

/* A sensor on the stage sees the part from where the stage is. */
static bool sense(void *data, double *mm)
{
	struct env *e = data;
	double pos[3], z;

	pthread_mutex_lock(&tracked_lock);
	memcpy(pos, tracked, sizeof(pos));
	pthread_mutex_unlock(&tracked_lock);
	if (mock_part_probe_z(e->part, pos[0], pos[1], 0, &z) < 0)
		return false;
	*mm = z - pos[2];
	return true;
}

static int setup(void **state)
{
	struct env *e = calloc(1, sizeof(*e));

	assert_non_null(e);
	scan_fixture_init(&e->fx, 150, "line");
	assert_int_equal(mock_part_new(&part_params, &e->part, NULL), 0);
	/* A sensor reports to 10 nm (the finest its format carries): 4000
	 * readings bring the fit's error from rounding under 1 nm, where 150
	 * leave it at about 3 nm */
	struct asph_plan_density d = { ASPH_DENSITY_POINTS, 4000 };
	struct asph_plan_options po = { .flags = ASPH_PLAN_NO_MESH };
	assert_int_equal(asph_plan_compute_opts(e->fx.s, ASPH_PLAN_FERMAT, d, &po, &e->dense, NULL), 0);
	e->plan = e->fx.plan;
	*state = e;
	return 0;
}

static int teardown(void **state)
{
	struct env *e = *state;

	mock_part_free(e->part);
	asph_plan_free(e->dense);
	scan_fixture_fini(&e->fx);
	free(e);
	return 0;
}

/* The reply timeout: answers come from a thread of this process, which
 * valgrind runs one at a time. */
static unsigned reply_ms(void)
{
	const char *v = getenv("ASPH_UNDER_VALGRIND");
	return v && *v && strcmp(v, "0") != 0 ? 2000 : 200;
}

/* Whether msg has one of the alternatives of words ("a|b"). */
static bool has_one_of(const char *msg, const char *words)
{
	char buf[256];

	snprintf(buf, sizeof(buf), "%s", words);
	char *save = NULL;
	for (char *w = strtok_r(buf, "|", &save); w; w = strtok_r(NULL, "|", &save))
		if (strstr(msg, w))
			return true;
	return false;
}

/* The simulator's stats once it has handled what the driver sent last
 * (it reads on its own thread): the stage standing and, when stopped is
 * set, stopped at least once; given up after 2 s (20 s under valgrind). */
static void settled_stats(struct linesim *sim, bool stopped, struct linesim_stats *st)
{
	for (unsigned i = 0; i < 10 * reply_ms(); i++) {
		linesim_stats(sim, st);
		if (!st->moving && (!stopped || st->stops >= 1))
			return;
		msleep(1);
	}
}

struct profile_case {
	const char *profile;
	enum linesim_kind kind;
	bool stage;
	const char *wrong_axes;         /* the axes option with a wrong id */
	const char *error_words;        /* the device's error, as reported */
	const char *wrong_axis_words;
	bool tcp_only;                  /* no serial line (linuxcncrsh) */
	bool wrong_axis_in_scan;        /* only a move (a reading) names the axes */
};

static const struct profile_case cases[] = {
	{ "pi-gcs", LINESIM_PI, true, "1,2,4", "PI error 7: position out of limits",
	  "axis z (4): enable: PI error 15: invalid axis identifier" },
	{ "newport-esp", LINESIM_NEWPORT, true, "1,2,4", "POSITIVE SOFTWARE LIMIT DETECTED",
	  "axis z (4): enable: Newport error 9: AXIS NUMBER OUT OF RANGE" },
	{ "aerotech-ascii", LINESIM_AEROTECH, true, "X,Y,W",
	  "Aerotech axis fault 16: CwSoftwareLimitFault",
	  "axis z (W): enable: Aerotech: the controller does not take the command" },
	/* G53 G0 X.. Y.. Q..: rs274ngc refuses the Q word at the first move */
	{ "linuxcnc", LINESIM_LINUXCNC, true, "X,Y,Q",
	  "LinuxCNC error: Move on line 0 would exceed joint",
	  "move: LinuxCNC error: Q word with no G5, G10, G64", true, true },
	{ "keyence-lk", LINESIM_KEYENCE, false, "2", "Keyence error 99: other error",
	  "read: Keyence error 1: status error", false, true },
	{ "mitutoyo-vcp", LINESIM_MITUTOYO, false, NULL, NULL, NULL },
	{ "sylvac", LINESIM_SYLVAC, false, NULL, "Sylvac error 0: sensor error", NULL },
};

/* The instrument: the profile's device on its simulator at address, and
 * the mock probe riding on it (a stage profile) or the mock stage
 * carrying it (a sensor profile). */
static struct asph_config *bench(struct env *e, const struct profile_case *pc, bool serial,
				 const char *address, const char *extra)
{
	char text[2048], dev[1024], conn[512];
	struct asph_config *c;
	struct asph_error err;

	if (serial)
		snprintf(conn, sizeof(conn), "\"device\": \"%s\"", address);
	else
		snprintf(conn, sizeof(conn), "\"port\": %s", address);
	snprintf(dev, sizeof(dev), "\"driver\": \"line\", \"options\": {\"profile\": \"%s\", %s, "
		 "\"timeout\": %u%s%s%s}", pc->profile, conn, reply_ms(),
		 pc->stage ? "" : ", \"standoff\": 0, \"range\": 1", extra ? ", " : "",
		 extra ? extra : "");
	if (pc->stage)
		snprintf(text, sizeof(text),
			 "{\"instruments\": [{\"name\": \"bench\", \"stage\": {%s},\n"
			 " \"probe\": {\"driver\": \"mock\", \"options\": {\"time_factor\": 0, "
			 MISALIGNMENT "}}}]}", dev);
	else
		snprintf(text, sizeof(text),
			 "{\"instruments\": [{\"name\": \"bench\", \"stage\": {\"driver\": \"mock\", "
			 "\"options\": {\"time_factor\": 0}},\n \"probe\": {%s}}]}", dev);
	if (asph_config_parse(e->fx.reg, text, strlen(text), "bench.json", &c, &err) < 0)
		fail_msg("%s", err.message);
	if (!pc->stage) {
		/* the mock stage, telling the sensor's simulator where it is */
		static struct asph_stage_ops ops;
		static struct asph_driver tracking;
		mock_stage = c->instruments[0].stage_driver->stage;
		ops = *mock_stage;
		ops.home = track_home;
		ops.move_to = track_move;
		tracking = *c->instruments[0].stage_driver;
		tracking.stage = &ops;
		c->instruments[0].stage_driver = &tracking;
	}
	return c;
}

struct rig {
	struct linesim *dev;
	char address[128];
};

/* The simulator of a case; link: a serial line reached through this
 * symbolic link, which comes back after a drop when replug. */
static void rig_start_link(struct env *e, const struct profile_case *pc, bool serial,
			   const char *link, bool replug, struct rig *rg)
{
	struct linesim_config sc = { .kind = pc->kind, .serial = serial, .time_scale = 1e-4,
				     .travel = 50, .speed = 20, .sense = sense, .sense_data = e,
				     .link = link, .replug = replug, .replug_s = 0.05 };

	memset(rg, 0, sizeof(*rg));
	assert_int_equal(linesim_start(&sc, &rg->dev, rg->address, sizeof(rg->address)), 0);
}

static void rig_start(struct env *e, const struct profile_case *pc, bool serial, struct rig *rg)
{
	rig_start_link(e, pc, serial, NULL, false, rg);
}

static void rig_stop(struct env *e, struct rig *rg)
{
	linesim_stop(rg->dev);
}

/* Measures the first n points of the plan with the first instrument of
 * c into path (fixture_scan). */
static int scan_n(struct env *e, struct asph_config *c, size_t n, const char *path,
		  struct asph_error *err, bool open_may_fail)
{
	return fixture_scan(&e->fx, &c->instruments[0], e->plan->xyz, n, path, err, open_may_fail);
}

static int scan(struct env *e, struct asph_config *c, const char *path, struct asph_error *err,
		bool open_may_fail)
{
	return scan_n(e, c, e->plan->n, path, err, open_may_fail);
}

static void fit(struct env *e, const char *path, struct asph_fit_result *res)
{
	fixture_fit_rigid(&e->fx, path, e->plan->n, res);
}

/* A whole scan of the strong preset over TCP and over a pty: the fit
 * returns the part's misalignment. */
static void scan_case(struct env *e, const struct profile_case *pc)
{
	static const double want[5] = { SHIFT_X, SHIFT_Y, SHIFT_Z, TILT_X, TILT_Y };
	struct asph_fit_result res;
	struct asph_error err;
	char path[128];
	struct rig rg;

	e->plan = pc->stage ? e->fx.plan : e->dense;
	for (int serial = 0; serial < (pc->tcp_only ? 1 : 2); serial++) {
		rig_start(e, pc, serial, &rg);
		struct asph_config *c = bench(e, pc, serial, rg.address, NULL);
		if (scan(e, c, new_path(&e->fx, path, sizeof(path)), &err, false) < 0)
			fail_msg("%s over %s: %s", pc->profile, serial ? "a pty" : "TCP", err.message);
		asph_config_free(c);
		struct linesim_stats st;
		settled_stats(rg.dev, false, &st);
		assert_false(st.moving);
		rig_stop(e, &rg);
		fit(e, path, &res);
		/* shifts to 1e-6 mm; tilts to 1e-7 rad, 1e-6 mm over 10 mm */
		for (int k = 0; k < 5; k++)
			if (fabs(res.value[ASPH_FIT_TX + k] - want[k]) > (k < 3 ? 1e-6 : 1e-7))
				fail_msg("%s over %s: dof %d is %.9g, the part's %.9g", pc->profile,
					 serial ? "a pty" : "TCP", k, res.value[ASPH_FIT_TX + k], want[k]);
	}
	e->plan = e->fx.plan;
}

static void test_scans(void **state)
{
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++)
		scan_case(*state, &cases[i]);
}

/* ------------------------------------------------------------ faults */

struct fault_case {
	enum linesim_fault fault;
	const char *words;              /* NULL: the case's own device error */
};

static void fault_scan(struct env *e, const struct profile_case *pc, const struct fault_case *fc)
{
	struct asph_error err;
	struct linesim_stats st;
	char path[128];
	struct rig rg;

	rig_start(e, pc, false, &rg);
	struct asph_config *c = bench(e, pc, false, rg.address, NULL);
	/* at the 40th move (a stage) or reading (a sensor) */
	linesim_inject(rg.dev, fc->fault, pc->stage ? 120 : 40);
	int r = scan(e, c, new_path(&e->fx, path, sizeof(path)), &err, false);
	const char *words = fc->words ? fc->words : pc->error_words;
	if (r >= 0 || !has_one_of(err.message, words))
		fail_msg("%s, fault %d: %d '%s', expected '%s'", pc->profile, fc->fault, r,
			 err.message, words);
	settled_stats(rg.dev, pc->stage, &st);
	/* the stage stands: stopped by the driver after a fault of its own
	 * (connecting again when the connection was lost), or still after
	 * the probe's */
	assert_false(st.moving);
	if (pc->stage)
		assert_true(st.stops >= 1);
	if (pc->stage && fc->fault == LINESIM_DISCONNECT)
		assert_int_equal(st.connections, 2);
	rig_stop(e, &rg);
	asph_config_free(c);
	struct asph_scanfile *s = read_scan(path);
	assert_int_equal(s->report.outcome, ASPH_SCANFILE_FAILED);
	assert_true(has_one_of(s->report.reason, words));
	if (!(s->n >= 10 && s->n < e->plan->n))
		fail_msg("%s, fault %d: %zu points recorded", pc->profile, fc->fault, s->n);
	asph_scanfile_free(s);
}

static void test_faults(void **state)
{
	static const struct fault_case faults[] = {
		{ LINESIM_DEVICE_ERROR, NULL },
		{ LINESIM_GARBLE, "garbled reply" },
		{ LINESIM_STALL, "no reply to '" },
		/* an end of file, or a reset when the simulator had not read all */
		{ LINESIM_DISCONNECT, "closed the connection|went away (Connection reset" },
		{ LINESIM_PARTIAL, "partial reply" },
	};
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++)
		for (size_t f = 0; f < sizeof(faults) / sizeof(faults[0]); f++)
			if (faults[f].words || cases[i].error_words)
				fault_scan(*state, &cases[i], &faults[f]);
}

/* The scan file of a scan that failed: it reads back, with the reason. */
static size_t failed_file(const char *path, const char *words)
{
	struct asph_scanfile *s = read_scan(path);
	size_t n = s->n;

	assert_int_equal(s->report.outcome, ASPH_SCANFILE_FAILED);
	if (!strstr(s->report.reason, words))
		fail_msg("the file's reason '%s' lacks '%s'", s->report.reason, words);
	asph_scanfile_free(s);
	return n;
}

/*
 * A wrong axis id. Where the profile names every axis when the stage is
 * opened (servo on, enable), the controller refuses it then, with its
 * reason and the axis, before anything moves. Where only a move names the
 * axes (LinuxCNC's MDI line) or a reading its channel (Keyence), the scan
 * fails at the first one: the reason is in the file, which reads back,
 * and the stage stands.
 */
static void test_wrong_axis(void **state)
{
	struct env *e = *state;
	struct asph_error err;
	char path[128], opt[64];
	struct rig rg;

	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		const struct profile_case *pc = &cases[i];
		if (!pc->wrong_axes)
			continue;
		rig_start(e, pc, false, &rg);
		snprintf(opt, sizeof(opt), "\"axes\": \"%s\"", pc->wrong_axes);
		struct asph_config *c = bench(e, pc, false, rg.address, opt);
		asph_error_clear(&err);
		int r = scan(e, c, new_path(&e->fx, path, sizeof(path)), &err, !pc->wrong_axis_in_scan);
		if (r >= 0 || !strstr(err.message, pc->wrong_axis_words))
			fail_msg("%s: %d '%s', expected '%s'", pc->profile, r, err.message,
				 pc->wrong_axis_words);
		if (pc->wrong_axis_in_scan)
			assert_int_equal(failed_file(path, pc->wrong_axis_words), 0);
		else
			assert_int_equal(access(path, F_OK), -1);    /* refused before a file */
		struct linesim_stats st;
		settled_stats(rg.dev, pc->stage && pc->wrong_axis_in_scan, &st);
		assert_false(st.moving);
		/* the refused move is the only one; a stage that got that far
		 * was stopped */
		assert_true(st.moves <= (pc->stage && pc->wrong_axis_in_scan ? 1u : 0u));
		if (pc->stage && pc->wrong_axis_in_scan)
			assert_true(st.stops >= 1);
		rig_stop(e, &rg);
		asph_config_free(c);
	}
}

/*
 * A serial line that drops in the middle of a move (a USB adapter
 * unplugged): the driver opens the port again as soon as it is back (the
 * same /dev/serial/by-id name, a new tty behind it) and stops the stage.
 * When the port does not come back, the reason says that the stage could
 * not be stopped from here. Either way the scan file reads back.
 */
static void serial_drop(struct env *e, const struct profile_case *pc, bool replug)
{
	struct asph_error err;
	struct linesim_stats st;
	char path[128], link[256], opt[64];
	struct rig rg;

	snprintf(link, sizeof(link), "%s/by-id-%s", e->fx.dir, pc->profile);
	rig_start_link(e, pc, true, link, replug, &rg);
	snprintf(opt, sizeof(opt), "\"reconnect_ms\": %u", replug ? 5 * reply_ms() : 300);
	struct asph_config *c = bench(e, pc, true, rg.address, opt);
	linesim_inject(rg.dev, LINESIM_DISCONNECT, 120);
	asph_error_clear(&err);
	int r = scan(e, c, new_path(&e->fx, path, sizeof(path)), &err, false);
	const char *words = replug ? "; opened the port again and stopped the stage"
				   : "again to stop the stage";
	if (r != -ENODEV || !strstr(err.message, "went away") || !strstr(err.message, words))
		fail_msg("%s: %d '%s', expected '%s'", pc->profile, r, err.message, words);
	if (!replug && !strstr(err.message, link))
		fail_msg("%s: '%s' does not name the port", pc->profile, err.message);
	size_t n = failed_file(path, words);
	if (!(n >= 10 && n < e->plan->n))
		fail_msg("%s: %zu points recorded", pc->profile, n);
	settled_stats(rg.dev, replug, &st);
	if (replug) {
		/* stopped at once, not at the move's end */
		assert_int_equal(st.connections, 1);
		assert_true(st.stops >= 1);
		assert_false(st.moving);
	} else {
		assert_int_equal(st.stops, 0);
	}
	rig_stop(e, &rg);
	asph_config_free(c);
}

static void test_serial_drop(void **state)
{
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++)
		if (cases[i].stage && !cases[i].tcp_only)
			serial_drop(*state, &cases[i], true);
	serial_drop(*state, &cases[0], false);
}

/* Readings the operator triggers (a foot switch) within the timeout, and
 * a DTR request on a line without DTR (a pty). */
struct presser {
	struct linesim *sim;
	unsigned ms;            /* after this long */
};

static void *press_later(void *data)
{
	struct presser *p = data;

	msleep(p->ms);
	linesim_operator(p->sim);
	return NULL;
}

static void test_triggers(void **state)
{
	static const struct profile_case gauge = { "mitutoyo-vcp", LINESIM_MITUTOYO, false };
	struct env *e = *state;
	struct asph_error err;
	struct asph_options *o;
	struct asph_device *d;
	struct asph_reading rd;
	struct asph_probe_context ctx = { 0 };
	struct rig rg;
	char opts[512];
	pthread_t th;
	const struct asph_driver *line = asph_registry_find(e->fx.reg, "line");

	for (int serial = 0; serial < 2; serial++) {
		rig_start(e, &gauge, serial, &rg);
		tracked[0] = 1.7, tracked[1] = -2.3, tracked[2] = -3.1;
		assert_int_equal(asph_options_new(line, &o, NULL), 0);
		snprintf(opts, sizeof(opts), "%s", rg.address);
		assert_int_equal(asph_options_set(o, "profile", "mitutoyo-vcp", NULL), 0);
		assert_int_equal(asph_options_set(o, serial ? "device" : "port", opts, NULL), 0);
		assert_int_equal(asph_options_set(o, "trigger", serial ? "dtr" : "operator", NULL), 0);
		assert_int_equal(asph_options_set(o, "range", "100", NULL), 0);
		if (line->probe->open(line, asph_options_values(o), 1000, &d, &err) < 0)
			fail_msg("open: %s", err.message);
		if (serial) {
			/* a pty has no modem lines: said, not a wrong number */
			assert_int_equal(line->probe->read(d, &ctx, &rd, 500, &err), -ENOTSUP);
			assert_non_null(strstr(err.message, "this line has no DTR"));
		} else {
			struct presser p = { rg.dev, 50 };
			double z;
			assert_int_equal(pthread_create(&th, NULL, press_later, &p), 0);
			int r = line->probe->read(d, &ctx, &rd, 2000, &err);
			pthread_join(th, NULL);
			if (r < 0)
				fail_msg("read: %s", err.message);
			assert_int_equal(mock_part_probe_z(e->part, 1.7, -2.3, 0, &z), 0);
			assert_true(fabs(rd.value - (z + 3.1)) < 0.5e-5);
			/* nobody presses */
			assert_int_equal(line->probe->read(d, &ctx, &rd, 100, &err), -ETIMEDOUT);
			assert_non_null(strstr(err.message, "data button or foot switch"));
		}
		line->probe->close(d);
		asph_options_free(o);
		rig_stop(e, &rg);
	}
}

/*
 * Readings the operator triggers, through the executor: the probe's
 * read_timeout option is how long the host waits for each (the default
 * would be 2000 ms), so a press 2.3 s after the request still makes the
 * reading. The wrapped read records the timeout the executor gives and
 * has the simulated operator press the gauge's button after a while.
 */
static const struct asph_probe_ops *line_probe_ops;
static struct linesim *gauge;
static unsigned press_ms, longest_timeout;

static int pressed_read(struct asph_device *d, const struct asph_probe_context *ctx,
			struct asph_reading *out, unsigned timeout_ms, struct asph_error *err)
{
	struct presser p = { gauge, press_ms };
	pthread_t th;

	if (timeout_ms > longest_timeout)
		longest_timeout = timeout_ms;
	assert_int_equal(pthread_create(&th, NULL, press_later, &p), 0);
	int r = line_probe_ops->read(d, ctx, out, timeout_ms, err);
	pthread_join(th, NULL);
	press_ms = 30;
	return r;
}

static void operator_scan(struct env *e, const char *extra, unsigned first_press_ms,
			  unsigned want_timeout)
{
	static const struct profile_case pc = { "mitutoyo-vcp", LINESIM_MITUTOYO, false };
	static struct asph_probe_ops ops;
	static struct asph_driver pressing;
	struct asph_error err;
	char path[128];
	struct rig rg;

	rig_start(e, &pc, false, &rg);
	struct asph_config *c = bench(e, &pc, false, rg.address, extra);
	line_probe_ops = c->instruments[0].probe_driver->probe;
	ops = *line_probe_ops;
	ops.read = pressed_read;
	pressing = *c->instruments[0].probe_driver;
	pressing.probe = &ops;
	c->instruments[0].probe_driver = &pressing;
	gauge = rg.dev;
	press_ms = first_press_ms;
	longest_timeout = 0;
	asph_error_clear(&err);
	if (scan_n(e, c, 3, new_path(&e->fx, path, sizeof(path)), &err, false) < 0)
		fail_msg("%s", err.message);
	assert_int_equal(longest_timeout, want_timeout);
	struct asph_scanfile *s = read_scan(path);
	assert_int_equal(s->report.outcome, ASPH_SCANFILE_COMPLETED);
	assert_int_equal(s->n, 3);
	asph_scanfile_free(s);
	rig_stop(e, &rg);
	asph_config_free(c);
}

static void test_read_timeout(void **state)
{
	/* without the option: the host's 2000 ms */
	operator_scan(*state, "\"trigger\": \"operator\"", 30, 2000);
	operator_scan(*state, "\"trigger\": \"operator\", \"read_timeout\": 4000", 2300, 4000);
}

/* stop() from another thread interrupts a move: the wait ends at once,
 * the stop command reaches the controller, and the stage stays stopped
 * until it is opened again. */
struct stopper {
	const struct asph_driver *drv;
	struct asph_device *d;
};

static void *stop_later(void *data)
{
	struct stopper *s = data;
	struct timespec ts = { 0, 80000000 };

	nanosleep(&ts, NULL);
	s->drv->stage->stop(s->d, NULL);
	return NULL;
}

static void test_stop(void **state)
{
	struct env *e = *state;
	const struct asph_driver *line = asph_registry_find(e->fx.reg, "line");
	struct linesim_config sc = { .kind = LINESIM_PI, .time_scale = 1, .travel = 50, .speed = 20 };
	struct linesim *sim;
	struct linesim_stats st;
	struct asph_options *o;
	struct asph_error err;
	struct stopper sp = { line, NULL };
	char port[32];
	double t[3] = { 40, -30, 10 };
	pthread_t th;

	assert_int_equal(linesim_start(&sc, &sim, port, sizeof(port)), 0);
	assert_int_equal(asph_options_new(line, &o, NULL), 0);
	assert_int_equal(asph_options_set(o, "port", port, NULL), 0);
	if (line->stage->open(line, asph_options_values(o), 1000, &sp.d, &err) < 0)
		fail_msg("open: %s", err.message);
	if (line->stage->home(sp.d, 5000, &err) < 0)
		fail_msg("home: %s", err.message);
	assert_int_equal(pthread_create(&th, NULL, stop_later, &sp), 0);
	/* 2 s of motion at 20 mm/s */
	int r = line->stage->move_to(sp.d, t, 60000, &err);
	pthread_join(th, NULL);
	if (r != -ECANCELED)
		fail_msg("%d %s", r, err.message);
	/* the simulator takes the stop command from its own thread: until
	 * then, the axes move on (at most the rest of the 2 s move) */
	for (int i = 0; i < 400; i++) {
		linesim_stats(sim, &st);
		if (!st.moving)
			break;
		nanosleep(&(struct timespec){ 0, 5000000 }, NULL);
	}
	assert_false(st.moving);
	assert_true(st.stops >= 1);
	assert_true(st.position[0] > 0 && st.position[0] < 40);
	assert_int_equal(line->stage->move_to(sp.d, t, 1000, &err), -ECANCELED);
	line->stage->close(sp.d);
	asph_options_free(o);
	linesim_stop(sim);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_profile_refusals),
		cmocka_unit_test(test_builtin_profiles),
		cmocka_unit_test(test_reader),
		cmocka_unit_test(test_patterns),
		cmocka_unit_test_setup_teardown(test_scans, setup, teardown),
		cmocka_unit_test_setup_teardown(test_faults, setup, teardown),
		cmocka_unit_test_setup_teardown(test_wrong_axis, setup, teardown),
		cmocka_unit_test_setup_teardown(test_serial_drop, setup, teardown),
		cmocka_unit_test_setup_teardown(test_read_timeout, setup, teardown),
		cmocka_unit_test_setup_teardown(test_triggers, setup, teardown),
		cmocka_unit_test_setup_teardown(test_stop, setup, teardown),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
