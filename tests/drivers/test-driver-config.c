/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The registry, option values, specs, configuration files and plugins. */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmocka.h>

#include "asph-driver/instrument.h"

struct fixture {
	struct asph_registry *reg;
};

static int setup(void **state)
{
	struct fixture *f = calloc(1, sizeof(*f));
	assert_non_null(f);
	assert_int_equal(asph_registry_new(&f->reg, NULL), 0);
	*state = f;
	return 0;
}

static int teardown(void **state)
{
	struct fixture *f = *state;
	asph_registry_free(f->reg);
	free(f);
	return 0;
}

static void test_builtin(void **state)
{
	struct fixture *f = *state;
	const struct asph_driver *mock = asph_registry_find(f->reg, "mock");

	assert_non_null(mock);
	assert_non_null(asph_registry_find(f->reg, "replay"));
	assert_null(asph_registry_find(f->reg, "nosuch"));
	assert_true(asph_registry_count(f->reg) >= 2);
	assert_int_equal(mock->roles, ASPH_ROLE_STAGE | ASPH_ROLE_PROBE);
	assert_string_equal(asph_registry_origin(f->reg, 0), "built-in");
	for (size_t i = 0; i < asph_registry_count(f->reg); i++)
		assert_int_equal(asph_driver_validate(asph_registry_get(f->reg, i), NULL), 0);
}

static const struct asph_probe_ops dummy_probe;

static void test_validate_refuses(void **state)
{
	static const struct asph_option_desc bad_default[] = {
		{ "speed", ASPH_OPTION_DOUBLE, "fast", .help = "h" },
	};
	static const struct asph_option_desc out_of_range[] = {
		{ "n", ASPH_OPTION_INT, "17", .ranged = true, .min = 1, .max = 10, .help = "h" },
	};
	struct asph_driver d = { .abi_version = ASPH_DRIVER_ABI_VERSION, .name = "x",
				 .roles = ASPH_ROLE_PROBE, .probe = &dummy_probe };
	struct asph_error err;

	/* missing operations */
	assert_int_equal(asph_driver_validate(&d, &err), -EINVAL);
	assert_non_null(strstr(err.message, "probe operations"));
	d.abi_version = 7;
	assert_int_equal(asph_driver_validate(&d, &err), -EPROTO);
	d = *asph_registry_find(((struct fixture *)*state)->reg, "mock");
	d.name = "Bad Name";
	assert_int_equal(asph_driver_validate(&d, &err), -EINVAL);
	d.name = "ok";
	d.options = bad_default;
	d.n_options = 1;
	assert_int_equal(asph_driver_validate(&d, &err), -EINVAL);
	assert_non_null(strstr(err.message, "speed"));
	d.options = out_of_range;
	assert_int_equal(asph_driver_validate(&d, &err), -ERANGE);
}

static void test_options(void **state)
{
	struct fixture *f = *state;
	const struct asph_driver *mock = asph_registry_find(f->reg, "mock");
	struct asph_options *o;
	struct asph_error err;
	char buf[64];

	assert_int_equal(asph_options_new(mock, &o, NULL), 0);
	const struct asph_option_value *v = asph_options_values(o);
	size_t rate = 0, probe = 0, stream = 0, seed = 0;
	for (size_t i = 0; i < mock->n_options; i++) {
		if (!strcmp(mock->options[i].name, "rate")) rate = i;
		if (!strcmp(mock->options[i].name, "probe")) probe = i;
		if (!strcmp(mock->options[i].name, "stream")) stream = i;
		if (!strcmp(mock->options[i].name, "seed")) seed = i;
	}
	assert_false(v[rate].set);
	assert_int_equal(asph_options_set(o, "rate", "23456.5", &err), 0);
	assert_true(v[rate].set);
	assert_true(v[rate].d == 23456.5);
	assert_int_equal(asph_options_set(o, "probe", "tactile", &err), 0);
	assert_int_equal(v[probe].i, 1);
	assert_string_equal(v[probe].s, "tactile");
	assert_int_equal(asph_options_set(o, "stream", "off", &err), 0);
	assert_false(v[stream].b);
	assert_int_equal(asph_options_set(o, "seed", "91733", &err), 0);
	assert_int_equal(v[seed].i, 91733);
	assert_string_equal(asph_option_value_format(&v[seed], buf, sizeof(buf)), "91733");

	assert_int_equal(asph_options_set(o, "rates", "1", &err), -ENOENT);
	assert_string_equal(err.field, "rates");
	assert_int_equal(asph_options_set(o, "rate", "fast", &err), -EINVAL);
	assert_string_equal(err.field, "rate");
	assert_int_equal(asph_options_set(o, "rate", "1e999", &err), -EINVAL);
	assert_int_equal(asph_options_set(o, "rate", "-3", &err), -ERANGE);
	assert_non_null(strstr(err.message, "outside"));
	assert_int_equal(asph_options_set(o, "seed", "12.5", &err), -EINVAL);
	/* ids as datasheets print them; a leading zero is still decimal */
	assert_int_equal(asph_options_set(o, "seed", "0x1A2b", &err), 0);
	assert_string_equal(asph_option_value_format(&v[seed], buf, sizeof(buf)), "6699");
	assert_int_equal(asph_options_set(o, "seed", "0017", &err), 0);
	assert_string_equal(asph_option_value_format(&v[seed], buf, sizeof(buf)), "17");
	assert_int_equal(asph_options_set(o, "seed", "0x", &err), -EINVAL);
	assert_int_equal(asph_options_set(o, "seed", "0x1g", &err), -EINVAL);
	assert_int_equal(asph_options_set(o, "probe", "laser", &err), -ERANGE);
	assert_non_null(strstr(err.message, "optical, tactile"));
	assert_int_equal(asph_options_set(o, "stream", "maybe", &err), -EINVAL);
	/* a refused value leaves the previous one */
	assert_true(v[rate].d == 23456.5);
	asph_options_free(o);
}

static const struct asph_option_value *spec_value(const struct asph_config *c,
						  const char *name)
{
	const struct asph_driver *d = c->instruments[0].probe_driver;
	for (size_t i = 0; i < d->n_options; i++)
		if (!strcmp(d->options[i].name, name))
			return &asph_options_values(c->instruments[0].probe_options)[i];
	fail_msg("no option %s", name);
	return NULL;
}

/* The mock's part is the lens being measured unless the configuration
 * names another; each job replaces the last job's lens. */
static void test_lens_follows_job(void **state)
{
	struct fixture *f = *state;
	struct asph_config *c;
	struct asph_error err;

	assert_int_equal(asph_instrument_spec_parse(f->reg, "mock", &c, &err), 0);
	assert_string_equal(spec_value(c, "lens")->s, "");
	assert_int_equal(asph_instrument_config_set_lens(&c->instruments[0], "{\"a\":1}", &err), 0);
	assert_string_equal(spec_value(c, "lens")->s, "{\"a\":1}");
	assert_false(spec_value(c, "lens")->set);
	assert_int_equal(asph_instrument_config_set_lens(&c->instruments[0], "{\"b\":2}", &err), 0);
	assert_string_equal(spec_value(c, "lens")->s, "{\"b\":2}");
	asph_config_free(c);

	assert_int_equal(asph_instrument_spec_parse(f->reg, "mock:lens=weak", &c, &err), 0);
	assert_int_equal(asph_instrument_config_set_lens(&c->instruments[0], "{\"a\":1}", &err), 0);
	assert_string_equal(spec_value(c, "lens")->s, "weak");
	assert_true(spec_value(c, "lens")->set);
	asph_config_free(c);
}

/* A worker's copy of an instrument is the whole instrument: its options and
 * its acquisition settings. */
static void test_config_copy(void **state)
{
	struct fixture *f = *state;
	struct asph_config *c, *copy;
	struct asph_error err;

	assert_int_equal(asph_instrument_spec_parse(f->reg, "mock:rate=2500,settle_dwell=0.03,"
		"drift_interval=900points,drift_references=1:2;-3:4,retries=5", &c, &err), 0);
	assert_int_equal(asph_instrument_config_copy(&c->instruments[0], &copy, &err), 0);
	const struct asph_acquisition *a = &copy->instruments[0].acquisition;
	assert_true(spec_value(copy, "rate")->d == 2500);
	assert_true(a->settle_dwell == 0.03);
	assert_int_equal(a->drift_interval_points, 900);
	assert_int_equal(a->n_references, 2);
	assert_true(a->references[1][0] == -3 && a->references[1][1] == 4);
	assert_int_equal(a->retries, 5);
	asph_config_free(copy);
	asph_config_free(c);
}

static void test_spec(void **state)
{
	struct fixture *f = *state;
	struct asph_config *c;
	struct asph_error err;

	assert_int_equal(asph_instrument_spec_parse(f->reg, "mock", &c, &err), 0);
	assert_int_equal(c->n, 1);
	assert_string_equal(c->instruments[0].name, "mock");
	assert_false(spec_value(c, "rate")->set);
	asph_config_free(c);

	assert_int_equal(asph_instrument_spec_parse(f->reg, "mock:rate=20000", &c, &err), 0);
	assert_true(spec_value(c, "rate")->d == 20000);
	asph_config_free(c);

	assert_int_equal(asph_instrument_spec_parse(f->reg, "mock:fail_after=500,form=4:30;9:-12", &c,
						    &err), 0);
	assert_int_equal(spec_value(c, "fail_after")->i, 500);
	assert_string_equal(spec_value(c, "form")->s, "4:30;9:-12");
	asph_config_free(c);

	assert_int_equal(asph_instrument_spec_parse(f->reg, "nosuch:x=1", &c, &err), -ENOENT);
	assert_non_null(strstr(err.message, "nosuch"));
	assert_int_equal(asph_instrument_spec_parse(f->reg, "mock:rate", &c, &err), -EINVAL);
	assert_int_equal(asph_instrument_spec_parse(f->reg, "mock:bogus=1", &c, &err), -ENOENT);
	assert_string_equal(err.field, "bogus");
	assert_int_equal(asph_instrument_spec_parse(f->reg, "mock:rate=0", &c, &err), -ERANGE);
	assert_string_equal(err.field, "rate");
	assert_string_equal(err.source, "mock:rate=0");
}

static const char good_json[] =
	"{\n"
	"  \"instruments\": [\n"
	"    { \"name\": \"bench\",\n"
	"      \"stage\": { \"driver\": \"mock\", \"options\": { \"speed\": 35.5, \"kinematics\": \"r-theta-z\" } },\n"
	"      \"probe\": { \"driver\": \"mock\", \"options\": { \"rate\": 20000, \"stream\": false } } },\n"
	"    { \"stage\": { \"driver\": \"mock\" }, \"probe\": { \"driver\": \"replay\",\n"
	"        \"options\": { \"file\": \"x.asph\" } } }\n"
	"  ]\n"
	"}\n";

static void test_config_file(void **state)
{
	struct fixture *f = *state;
	struct asph_config *c;
	struct asph_error err;
	char *json;

	assert_int_equal(asph_config_parse(f->reg, good_json, strlen(good_json), "a.json", &c, &err), 0);
	assert_int_equal(c->n, 2);
	assert_string_equal(c->instruments[0].name, "bench");
	assert_string_equal(c->instruments[1].name, "instrument2");
	assert_string_equal(c->instruments[1].probe_driver->name, "replay");
	assert_int_equal(asph_instrument_config_to_json(&c->instruments[0], &json), 0);
	assert_non_null(strstr(json, "\"speed\":35.5"));
	assert_non_null(strstr(json, "\"kinematics\":\"r-theta-z\""));
	/* stage-only options stay out of the probe's part */
	assert_null(strstr(strstr(json, "\"probe\""), "kinematics"));
	assert_null(strstr(json, "uncertainty"));
	assert_false(c->instruments[0].has_uncertainty);
	free(json);
	asph_config_free(c);
}

static const char uncertainty_json[] =
	"{\"instruments\": [\n"
	" {\"stage\": {\"driver\": \"mock\"}, \"probe\": {\"driver\": \"mock\"},\n"
	"  \"uncertainty\": {\"probe_noise_nm\": 4.5, \"position_noise_um\": 0.25,\n"
	"    \"position_resolution_um\": 0.05, \"latency_us\": 30, \"scan_speed_mm_s\": 8,\n"
	"    \"drift_residual_nm\": 6, \"tip_radius_um\": 0.4}}]}\n";

/* The instrument's declared uncertainty contributions: read, recorded in
 * the instrument's JSON (the scan header) and kept by a copy. */
static void test_config_uncertainty(void **state)
{
	struct fixture *f = *state;
	struct asph_config *c, *copy;
	struct asph_error err;
	char *json;

	assert_int_equal(asph_config_parse(f->reg, uncertainty_json, strlen(uncertainty_json),
					   "u.json", &c, &err), 0);
	const struct asph_instrument_config *ic = &c->instruments[0];
	assert_true(ic->has_uncertainty);
	assert_true(ic->uncertainty.probe_noise_nm == 4.5);
	assert_true(ic->uncertainty.position_noise_um == 0.25);
	assert_true(ic->uncertainty.position_resolution_um == 0.05);
	assert_true(ic->uncertainty.latency_us == 30);
	assert_true(ic->uncertainty.scan_speed_mm_s == 8);
	assert_true(ic->uncertainty.drift_residual_nm == 6);
	assert_true(ic->uncertainty.tip_radius_um == 0.4);
	assert_int_equal(asph_instrument_config_copy(ic, &copy, &err), 0);
	assert_true(copy->instruments[0].has_uncertainty);
	assert_memory_equal(&copy->instruments[0].uncertainty, &ic->uncertainty,
			    sizeof(ic->uncertainty));
	assert_int_equal(asph_instrument_config_to_json(&copy->instruments[0], &json), 0);
	assert_non_null(strstr(json, "\"uncertainty\":{\"probe_noise_nm\":4.5,"));
	assert_non_null(strstr(json, "\"tip_radius_um\":0.40000000000000002"));
	free(json);
	asph_config_free(copy);
	asph_config_free(c);
}

struct bad_case {
	const char *text;
	int code, line, column;
	const char *field;
	const char *words;
};

static void test_config_refusals(void **state)
{
	static const struct bad_case cases[] = {
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\"},\n  \"probe\": {\"driver\": \"mock\", \"options\": {\"rat\": 5}}}]}",
		  -ENOENT, 3, 43, "instruments.[0].probe.options.rat", "no option 'rat'" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\"},\n  \"probe\": {\"driver\": \"mock\", \"options\": {\"rate\": \"fast\"}}}]}",
		  -EINVAL, 3, 43, "instruments.[0].probe.options.rate", "expects a number" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\", \"options\": {\"speed\": -2}},\n  \"probe\": {\"driver\": \"mock\"}}]}",
		  -ERANGE, 2, 43, "instruments.[0].stage.options.speed", "outside" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"nosuch\"},\n  \"probe\": {\"driver\": \"mock\"}}]}",
		  -ENOENT, 2, 13, "instruments.[0].stage.driver", "no driver 'nosuch'" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\"}}]}",
		  -EINVAL, 2, 2, "instruments.[0].probe", "missing" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\"}, \"probe\": {\"driver\": \"mock\"},\n  \"colour\": 1}]}",
		  -EINVAL, 3, 3, "instruments.[0].colour", "unknown member" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\" \"probe\": 1}]}",
		  -EINVAL, 2, 36, "", "expected" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\", \"options\": {\"stream\": 1}}, \"probe\": {\"driver\": \"mock\"}}]}",
		  -EINVAL, 2, 43, "instruments.[0].stage.options.stream", "true or false" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\"}, \"probe\": {\"driver\": \"mock\"},\n  \"uncertainty\": {\"probe_noise\": 4}}]}",
		  -ENOENT, 3, 19, "instruments.[0].uncertainty.probe_noise", "probe_noise_nm" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\"}, \"probe\": {\"driver\": \"mock\"},\n  \"uncertainty\": {\"tip_radius_um\": -0.1}}]}",
		  -EINVAL, 3, 19, "instruments.[0].uncertainty.tip_radius_um", ">= 0" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\"}, \"probe\": {\"driver\": \"mock\"},\n  \"uncertainty\": {\"latency_us\": \"20\"}}]}",
		  -EINVAL, 3, 19, "instruments.[0].uncertainty.latency_us", "must be a number" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\"}, \"probe\": {\"driver\": \"mock\"},\n  \"uncertainty\": {\"latency_us\": 20}}]}",
		  -EINVAL, 3, 3, "instruments.[0].uncertainty", "scan_speed_mm_s" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\"}, \"probe\": {\"driver\": \"mock\"},\n  \"uncertainty\": {\"latency_us\": 20,\n   \"scan_speed_mm_s\": 0}}]}",
		  -EINVAL, 4, 4, "instruments.[0].uncertainty.scan_speed_mm_s", "scan_speed_mm_s > 0" },
		{ "{\"instruments\": [\n {\"stage\": {\"driver\": \"mock\"}, \"probe\": {\"driver\": \"mock\"},\n  \"uncertainty\": [1]}]}",
		  -EINVAL, 3, 3, "instruments.[0].uncertainty", "an object of contributions" },
	};
	struct fixture *f = *state;

	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		struct asph_config *c = NULL;
		struct asph_error err;
		const struct bad_case *b = &cases[i];

		asph_error_clear(&err);
		int r = asph_config_parse(f->reg, b->text, strlen(b->text), "conf.json", &c, &err);
		if (r != b->code || err.line != b->line || err.column != b->column ||
		    strcmp(err.field, b->field) || !strstr(err.message, b->words))
			fail_msg("case %zu: %d at %d:%d field '%s': %s", i, r, err.line, err.column,
				 err.field, err.message);
		assert_string_equal(err.source, "conf.json");
		assert_null(c);
	}
}

static void test_resolve(void **state)
{
	struct fixture *f = *state;
	char path[] = "/tmp/asph-test-config-XXXXXX";
	int fd = mkstemp(path);
	struct asph_config *c;
	size_t idx;
	char arg[64];

	assert_true(fd >= 0);
	assert_int_equal(write(fd, good_json, strlen(good_json)), (ssize_t)strlen(good_json));
	close(fd);
	assert_int_equal(asph_config_resolve(f->reg, path, &c, &idx, NULL), 0);
	assert_int_equal(idx, 0);
	asph_config_free(c);
	snprintf(arg, sizeof(arg), "%s#instrument2", path);
	assert_int_equal(asph_config_resolve(f->reg, arg, &c, &idx, NULL), 0);
	assert_int_equal(idx, 1);
	asph_config_free(c);
	snprintf(arg, sizeof(arg), "%s#nosuch", path);
	assert_int_equal(asph_config_resolve(f->reg, arg, &c, &idx, NULL), -ENOENT);
	assert_int_equal(asph_config_resolve(f->reg, "mock:rate=5", &c, &idx, NULL), 0);
	asph_config_free(c);
	unlink(path);
}

static void test_plugins(void **state)
{
	const char *good = getenv("ASPH_TEST_PLUGIN_GOOD");
	const char *bad = getenv("ASPH_TEST_PLUGIN_BAD_ABI");
	struct asph_registry *reg;
	struct asph_error err;
	struct asph_config *c;

	if (!good || !bad)
		skip();
	assert_int_equal(asph_registry_new(&reg, NULL), 0);
	size_t n0 = asph_registry_count(reg);
	assert_int_equal(asph_registry_load_plugin(reg, bad, &err), -EPROTO);
	assert_non_null(strstr(err.message, "ABI 999"));
	assert_string_equal(err.source, bad);
	assert_int_equal(asph_registry_count(reg), n0);
	assert_int_equal(asph_registry_load_plugin(reg, "/nonexistent/x.so", &err), -ENOENT);
	assert_int_equal(asph_registry_load_plugin(reg, good, &err), 0);
	assert_int_equal(asph_registry_count(reg), n0 + 1);
	assert_string_equal(asph_registry_origin(reg, n0), good);
	const struct asph_driver *echo = asph_registry_find(reg, "echo");
	assert_non_null(echo);
	assert_int_equal(echo->roles, ASPH_ROLE_PROBE);
	/* the same plugin twice: a name clash */
	assert_int_equal(asph_registry_load_plugin(reg, good, &err), -EEXIST);

	/* a probe-only driver can be a probe, not a stage */
	static const char conf[] =
		"{\"instruments\": [{\"stage\": {\"driver\": \"mock\"},"
		" \"probe\": {\"driver\": \"echo\", \"options\": {\"height\": 0.125}}}]}";
	assert_int_equal(asph_config_parse(reg, conf, strlen(conf), "p.json", &c, &err), 0);
	struct asph_instrument *inst;
	assert_int_equal(asph_instrument_open(&c->instruments[0], 1000, &inst, &err), 0);
	struct asph_reading rd;
	struct asph_probe_context ctx = { 0 };
	assert_int_equal(inst->probe_driver->probe->read(inst->probe, &ctx, &rd, 100, &err), 0);
	assert_true(rd.value == 0.125);
	asph_instrument_close(inst);
	asph_config_free(c);
	assert_int_equal(asph_instrument_spec_parse(reg, "echo", &c, &err), -EINVAL);
	assert_non_null(strstr(err.message, "cannot be a stage"));
	asph_registry_free(reg);
}

/* A plugin built against the ABI 1.0 header loads, reads and streams
 * through this host (its shorter structures converted), and says where it
 * was; one of a newer minor version than the host's is refused. */
static void test_plugin_abi_1_0(void **state)
{
	const char *old = getenv("ASPH_TEST_PLUGIN_ABI10");
	const char *newer = getenv("ASPH_TEST_PLUGIN_NEWER");
	struct asph_registry *reg;
	struct asph_error err;
	struct asph_config *c;
	char want[64];

	if (!old || !newer)
		skip();
	assert_int_equal(asph_registry_new(&reg, NULL), 0);
	assert_int_equal(asph_registry_load_plugin(reg, newer, &err), -EPROTO);
	snprintf(want, sizeof(want), "ABI %d.%d, this program has ABI %d.%d", ASPH_DRIVER_ABI_MAJOR,
		 ASPH_DRIVER_ABI_MINOR + 1, ASPH_DRIVER_ABI_MAJOR, ASPH_DRIVER_ABI_MINOR);
	if (!strstr(err.message, want))
		fail_msg("%s", err.message);
	assert_int_equal(asph_registry_load_plugin(reg, old, &err), 0);
	const struct asph_driver *echo = asph_registry_find(reg, "echo");
	assert_non_null(echo);
	assert_int_equal(echo->abi_version, 1);
	assert_int_equal(asph_driver_abi_minor(echo), 0);

	static const char conf[] =
		"{\"instruments\": [{\"stage\": {\"driver\": \"mock\"},"
		" \"probe\": {\"driver\": \"echo\", \"options\": {\"height\": -0.375}}}]}";
	assert_int_equal(asph_config_parse(reg, conf, strlen(conf), "p.json", &c, &err), 0);
	char *json;
	assert_int_equal(asph_instrument_config_to_json(&c->instruments[0], &json), 0);
	assert_non_null(strstr(json, "\"driver\":\"echo\",\"version\":\"0.1\",\"abi\":\"1.0\""));
	free(json);
	struct asph_instrument *inst;
	assert_int_equal(asph_instrument_open(&c->instruments[0], 1000, &inst, &err), 0);
	/* what 1.0 does not have is not called, and 0 */
	assert_null(inst->probe_ops.attach);
	assert_false(inst->attached);
	assert_true(inst->probe_info.can_stream);
	assert_true(inst->probe_info.latency == 0);
	struct asph_probe_context ctx[5];
	struct asph_reading rd[5];
	memset(ctx, 0, sizeof(ctx));
	memset(rd, 0x5a, sizeof(rd));
	assert_int_equal(asph_instrument_read(inst, ctx, rd, 100, &err), 0);
	assert_true(rd[0].value == -0.375);
	assert_int_equal(rd[0].position_source, ASPH_POSITION_NONE);
	/* a stream: the plugin writes readings of the 1.0 size */
	for (int i = 0; i < 5; i++) {
		ctx[i].plan_index = 40 + (uint64_t)i;
		ctx[i].kind = ASPH_MEASURE_REFERENCE;
		ctx[i].attempt = 3;
	}
	size_t done;
	memset(rd, 0x5a, sizeof(rd));
	assert_int_equal(asph_instrument_stream(inst, ctx, 5, rd, &done, 100, &err), 0);
	assert_int_equal(done, 5);
	for (int i = 0; i < 5; i++) {
		assert_true(rd[i].value == -0.375);
		assert_true(rd[i].raw == 40 + i);
		assert_int_equal(rd[i].flags, 0);
		assert_int_equal(rd[i].position_source, ASPH_POSITION_NONE);
		assert_true(rd[i].position[0] == 0 && rd[i].position_t_ns == 0);
	}
	asph_instrument_close(inst);
	asph_config_free(c);
	asph_registry_free(reg);
}

static int warnings;

static void count_warning(const struct asph_error *err, void *data)
{
	warnings++;
	assert_int_equal(err->code, -EPROTO);
}

static void test_plugin_dir(void **state)
{
	const char *good = getenv("ASPH_TEST_PLUGIN_GOOD");
	const char *bad = getenv("ASPH_TEST_PLUGIN_BAD_ABI");
	char dir[] = "/tmp/asph-test-plugins-XXXXXX", a[128], b[128];
	struct asph_registry *reg;

	if (!good || !bad)
		skip();
	assert_non_null(mkdtemp(dir));
	snprintf(a, sizeof(a), "%s/echo.so", dir);
	snprintf(b, sizeof(b), "%s/old.so", dir);
	assert_int_equal(symlink(good, a), 0);
	assert_int_equal(symlink(bad, b), 0);
	assert_int_equal(asph_registry_new(&reg, NULL), 0);
	warnings = 0;
	assert_int_equal(asph_registry_load_dir(reg, dir, count_warning, NULL, NULL), 1);
	assert_int_equal(warnings, 1);
	assert_non_null(asph_registry_find(reg, "echo"));
	assert_int_equal(asph_registry_load_dir(reg, "/nonexistent-dir", NULL, NULL, NULL), 0);
	asph_registry_free(reg);
	unlink(a);
	unlink(b);
	rmdir(dir);
}

/* Copies the file at from to to with mode. */
static void copy_file(const char *from, const char *to, mode_t mode)
{
	char buf[65536];
	FILE *in = fopen(from, "rb"), *out = fopen(to, "wb");
	size_t n;

	assert_non_null(in);
	assert_non_null(out);
	while ((n = fread(buf, 1, sizeof(buf), in)) > 0)
		assert_int_equal(fwrite(buf, 1, n, out), n);
	fclose(in);
	fclose(out);
	assert_int_equal(chmod(to, mode), 0);
}

static bool marked(const char *mark)
{
	return access(mark, F_OK) == 0;
}

/* A plugin others could have written is refused before any of its code
 * runs (its constructor leaves a mark); a trusted copy loads. */
static void test_plugin_trust(void **state)
{
	const char *good = getenv("ASPH_TEST_PLUGIN_GOOD");
	char dir[] = "/tmp/asph-test-trust-XXXXXX", so[128], mark[128], sub[128];
	struct asph_registry *reg;
	struct asph_error err;

	if (!good)
		skip();
	assert_non_null(mkdtemp(dir));
	assert_int_equal(chmod(dir, 0755), 0);
	snprintf(so, sizeof(so), "%s/echo.so", dir);
	snprintf(mark, sizeof(mark), "%s/mark", dir);
	setenv("ASPH_TEST_PLUGIN_MARK", mark, 1);
	assert_int_equal(asph_registry_new(&reg, NULL), 0);

	copy_file(good, so, 0666);
	asph_error_clear(&err);
	assert_int_equal(asph_registry_load_plugin(reg, so, &err), -EPERM);
	assert_non_null(strstr(err.message, "writable by every user"));
	assert_false(marked(mark));
	assert_int_equal(chmod(so, 0664), 0);
	assert_int_equal(asph_registry_load_plugin(reg, so, &err), -EPERM);
	assert_false(marked(mark));
	/* A directory others may write, on the way. */
	assert_int_equal(chmod(so, 0755), 0);
	assert_int_equal(chmod(dir, 0777), 0);
	assert_int_equal(asph_registry_load_plugin(reg, so, &err), -EPERM);
	assert_non_null(strstr(err.message, "other users may write it"));
	assert_false(marked(mark));
	assert_int_equal(chmod(dir, 0755), 0);
	if (geteuid() == 0) {
		/* Another user's file, or one in another user's directory. */
		assert_int_equal(chown(so, 65534, 65534), 0);
		assert_int_equal(asph_registry_load_plugin(reg, so, &err), -EPERM);
		assert_non_null(strstr(err.message, "belongs to another user"));
		assert_int_equal(chown(so, 0, 0), 0);
		snprintf(sub, sizeof(sub), "%s/sub", dir);
		assert_int_equal(mkdir(sub, 0755), 0);
		assert_int_equal(chown(sub, 65534, 65534), 0);
		snprintf(so, sizeof(so), "%s/sub/echo.so", dir);
		copy_file(good, so, 0755);
		assert_int_equal(asph_registry_load_plugin(reg, so, &err), -EPERM);
		assert_false(marked(mark));
		unlink(so);
		rmdir(sub);
		snprintf(so, sizeof(so), "%s/echo.so", dir);
	} else {
		print_message("not root: the cases of another user's files are left out\n");
	}
	assert_int_equal(asph_registry_load_plugin(reg, so, &err), 0);
	assert_true(marked(mark));
	assert_non_null(asph_registry_find(reg, "echo"));
	asph_registry_free(reg);
	unsetenv("ASPH_TEST_PLUGIN_MARK");
	unlink(mark);
	unlink(so);
	rmdir(dir);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test_setup_teardown(test_builtin, setup, teardown),
		cmocka_unit_test_setup_teardown(test_validate_refuses, setup, teardown),
		cmocka_unit_test_setup_teardown(test_options, setup, teardown),
		cmocka_unit_test_setup_teardown(test_lens_follows_job, setup, teardown),
		cmocka_unit_test_setup_teardown(test_config_copy, setup, teardown),
		cmocka_unit_test_setup_teardown(test_spec, setup, teardown),
		cmocka_unit_test_setup_teardown(test_config_file, setup, teardown),
		cmocka_unit_test_setup_teardown(test_config_refusals, setup, teardown),
		cmocka_unit_test_setup_teardown(test_config_uncertainty, setup, teardown),
		cmocka_unit_test_setup_teardown(test_resolve, setup, teardown),
		cmocka_unit_test(test_plugins),
		cmocka_unit_test(test_plugin_dir),
		cmocka_unit_test(test_plugin_abi_1_0),
		cmocka_unit_test(test_plugin_trust),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
