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

#include "asph/executor.h"
#include "asph/fit.h"
#include "line-sim.h"
#include "line/profile.h"
#include "line/protocol.h"
#include "mock/protocol.h"
#include "scan-fixture.h"

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

/* Every built-in profile parses and has what its role needs. */
static void test_builtin_profiles(void **state)
{
	static const char *const names[] = {
		"pi-gcs", "keyence-lk", "mitutoyo-vcp", "sylvac",
	};
	const char *dir = getenv("ASPH_LINE_PROFILE_PATH");
	char path[512], *text;
	struct line_profile p;
	struct asph_error err;

	assert_non_null(dir);
	for (size_t i = 0; i < sizeof(names) / sizeof(names[0]); i++) {
		snprintf(path, sizeof(path), "%s/%s.profile", dir, names[i]);
		FILE *f = fopen(path, "r");
		assert_non_null(f);
		text = calloc(1, 1 << 16);
		size_t n = fread(text, 1, (1 << 16) - 1, f);
		fclose(f);
		if (line_profile_parse(text, n, path, &p, &err) < 0)
			fail_msg("%s:%d:%d: %s", path, err.line, err.column, err.message);
		assert_string_equal(p.name, names[i]);
		assert_true(p.reference[0] && p.description[0]);
		free(text);
	}
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
	struct mock_part *part;
	struct linesim *stage_sim;      /* what the sensor rides on */
};

static const struct mock_part_params part_params = {
	.lens = "strong",
	.pose = { .t = { SHIFT_X, SHIFT_Y, SHIFT_Z }, .rx = TILT_X, .ry = TILT_Y },
	.seed = 1,
};

/* A sensor on the simulated stage sees the part from where it is. */
static bool sense(void *data, double *mm)
{
	struct env *e = data;
	double pos[3], z;

	linesim_position(e->stage_sim, pos);
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
	*state = e;
	return 0;
}

static int teardown(void **state)
{
	struct env *e = *state;

	mock_part_free(e->part);
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

struct profile_case {
	const char *profile;
	enum linesim_kind kind;
	bool stage;
	const char *wrong_axes;         /* the axes option with a wrong id */
	const char *error_words;        /* the device's error, as reported */
	const char *wrong_axis_words;
};

static const struct profile_case cases[] = {
	{ "pi-gcs", LINESIM_PI, true, "1,2,4", "PI error 7: position out of limits",
	  "PI error 15: invalid axis identifier" },
	{ "keyence-lk", LINESIM_KEYENCE, false, "2", "Keyence error 99: other error",
	  "Keyence error 1: status error" },
	{ "mitutoyo-vcp", LINESIM_MITUTOYO, false, NULL, NULL, NULL },
	{ "sylvac", LINESIM_SYLVAC, false, NULL, "Sylvac error 0: sensor error", NULL },
};

/* The instrument: the profile's device on its simulator, and the mock
 * stage or probe for the other role. */
static struct asph_config *bench(struct env *e, const struct profile_case *pc, bool serial,
				 const char *address, const char *axes)
{
	char text[2048], conn[512], line[1024];
	struct asph_config *c;
	struct asph_error err;

	if (serial)
		snprintf(conn, sizeof(conn), "\"device\": \"%s\"", address);
	else
		snprintf(conn, sizeof(conn), "\"port\": %s", address);
	if (pc->stage) {
		snprintf(line, sizeof(line), "\"driver\": \"line\", \"options\": {\"profile\": \"%s\", "
			 "%s, \"timeout\": %u%s%s%s}", pc->profile, conn, reply_ms(),
			 axes ? ", \"axes\": \"" : "", axes ? axes : "", axes ? "\"" : "");
		snprintf(text, sizeof(text),
			 "{\"instruments\": [{\"name\": \"bench\", \"stage\": {%s},\n"
			 " \"probe\": {\"driver\": \"mock\", \"options\": {\"time_factor\": 0, "
			 MISALIGNMENT "}}}]}", line);
	} else {
		snprintf(line, sizeof(line), "\"driver\": \"line\", \"options\": {\"profile\": \"%s\", "
			 "%s, \"timeout\": %u, \"standoff\": 0, \"range\": 1%s%s%s}", pc->profile, conn,
			 reply_ms(), axes ? ", \"axes\": \"" : "", axes ? axes : "", axes ? "\"" : "");
		snprintf(text, sizeof(text),
			 "{\"instruments\": [{\"name\": \"bench\", \"stage\": {\"driver\": \"line\", "
			 "\"options\": {\"profile\": \"pi-gcs\", \"port\": %s, \"timeout\": %u}},\n"
			 " \"probe\": {%s}}]}", "@STAGE@", reply_ms(), line);
	}
	if (asph_config_parse(e->fx.reg, text, strlen(text), "bench.json", &c, &err) < 0)
		fail_msg("%s", err.message);
	return c;
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_profile_refusals),
		cmocka_unit_test(test_builtin_profiles),
		cmocka_unit_test(test_reader),
		cmocka_unit_test(test_patterns),
	};
	(void)bench;
	(void)cases;
	(void)setup;
	(void)teardown;
	(void)sense;
	return cmocka_run_group_tests(tests, NULL, NULL);
}
