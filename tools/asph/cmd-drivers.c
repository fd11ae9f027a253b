/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asph drivers: every instrument driver with its roles and options. */
#include <getopt.h>
#include <stdio.h>
#include <string.h>

#include "acquire-tool.h"
#include "asph-tool.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_registry *, asph_registry_free)

static int print_json(const struct asph_registry *reg)
{
	_cleanup_free_ char *text = NULL;
	struct asph_error err;
	char buf[640];

	asph_error_clear(&err);
	if (asph_registry_to_json(reg, true, &text, &err) < 0) {
		fprintf(stderr, "asph drivers: %s\n", asph_error_format(&err, buf, sizeof(buf)));
		return EXIT_FAILURE_RUN;
	}
	printf("%s\n", text);
	return EXIT_OK;
}

static void print_option(const struct asph_option_desc *o)
{
	char range[96] = "", dflt[80];

	if (o->ranged)
		snprintf(range, sizeof(range), " [%.10g .. %.10g]", o->min, o->max);
	if (o->choices) {
		size_t used = snprintf(range, sizeof(range), " {");
		for (size_t i = 0; o->choices[i] && used < sizeof(range); i++)
			used += snprintf(range + used, sizeof(range) - used, "%s%s", i ? "|" : "",
					 o->choices[i]);
		if (used < sizeof(range))
			snprintf(range + used, sizeof(range) - used, "}");
	}
	snprintf(dflt, sizeof(dflt), "%s%s%s", *o->default_value ? o->default_value : "\"\"",
		 o->unit ? " " : "", o->unit ? o->unit : "");
	printf("    %-16s %-7s default %s%s\n", o->name, asph_option_type_name(o->type), dflt, range);
	printf("    %-16s %s\n", "", o->help);
}

static const char *roles_text(unsigned roles)
{
	if ((roles & ASPH_ROLE_STAGE) && (roles & ASPH_ROLE_PROBE))
		return "stage, probe";
	return roles & ASPH_ROLE_STAGE ? "stage" : roles & ASPH_ROLE_PROBE ? "probe" : "-";
}

/* The profiles the driver's "profile" option can name, found now; -errno
 * having said why when they cannot be listed. */
static int print_profiles(const struct asph_registry *reg, size_t i)
{
	_cleanup_free_ struct asph_driver_profile *v = NULL;
	struct asph_error err;
	char buf[640];
	size_t n = 0;
	int r;

	asph_error_clear(&err);
	r = asph_registry_profiles(reg, i, &v, &n, &err);
	if (r < 0) {
		fflush(stdout);
		fprintf(stderr, "asph drivers: %s\n", asph_error_format(&err, buf, sizeof(buf)));
		return r;
	}
	if (n == 0)
		return 0;
	printf("  Profiles (option profile), as found in the profile directories and built in:\n");
	for (size_t k = 0; k < n; k++) {
		if (v[k].error[0]) {
			printf("    %-16s does not load: %s\n", v[k].name, v[k].error);
			continue;
		}
		printf("    %-16s %-7s %s\n", v[k].name, roles_text(v[k].roles), v[k].description);
		printf("    %-16s %-7s %s\n", "", "", v[k].path);
	}
	return 0;
}

static int print_text(const struct asph_registry *reg)
{
	int status = EXIT_OK;

	printf("Driver ABI %d\n", ASPH_DRIVER_ABI_VERSION);
	for (size_t i = 0; i < asph_registry_count(reg); i++) {
		const struct asph_driver *d = asph_registry_get(reg, i);
		printf("\n%s %s (%s%s%s), %s\n", d->name, d->version ? d->version : "",
		       d->roles & ASPH_ROLE_STAGE ? "stage" : "",
		       (d->roles & ASPH_ROLE_STAGE) && (d->roles & ASPH_ROLE_PROBE) ? ", " : "",
		       d->roles & ASPH_ROLE_PROBE ? "probe" : "", asph_registry_origin(reg, i));
		if (d->description)
			printf("  %s\n", d->description);
		if (d->n_options)
			printf("  Options:\n");
		for (size_t k = 0; k < d->n_options; k++)
			print_option(&d->options[k]);
		if (print_profiles(reg, i) < 0)
			status = EXIT_FAILURE_RUN;
	}
	return status;
}

static void usage(FILE *out)
{
	fprintf(out, "Usage: asph drivers [--json] [--plugin-dir DIR]\n\n"
		     "Lists the instrument drivers (built in and plugins) with their roles and options,\n"
		     "and the profile files a driver's profile option can name, as found now.\n"
		     "  --json             one JSON object\n"
		     "  --plugin-dir DIR   load plugins from DIR instead of $ASPH_DRIVER_PATH or the\n"
		     "                     installed plugin directory\n");
}

struct drivers_args {
	const char *plugin_dir;
	int json;
};

static int take(int opt, const char *arg, void *data)
{
	struct drivers_args *a = data;

	if (opt == 'j')
		a->json = 1;
	else
		a->plugin_dir = arg;
	return 0;
}

int cmd_drivers(int argc, char **argv)
{
	static const struct option long_opts[] = {
		{ "json", no_argument, NULL, 'j' },
		{ "plugin-dir", required_argument, NULL, 'P' },
		{ "help", no_argument, NULL, 'h' },
		{ NULL, 0, NULL, 0 },
	};
	_cleanup_(asph_registry_freep) struct asph_registry *reg = NULL;
	struct drivers_args a = { 0 };
	int code = tool_getopt(argc, argv, "h", long_opts, usage, take, &a);

	if (code >= 0)
		return code;
	if (optind != argc) {
		fprintf(stderr, "asph drivers: unexpected argument '%s'\n", argv[optind]);
		return EXIT_USAGE;
	}
	if (tool_registry_new(a.plugin_dir, &reg) < 0)
		return EXIT_FAILURE_RUN;
	if (a.json)
		return print_json(reg);
	return print_text(reg);
}
