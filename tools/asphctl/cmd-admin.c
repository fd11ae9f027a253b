/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asphctl lock, unlock, token. */
#include <errno.h>
#include <getopt.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asphctl.h"
#include "util-mem.h"
#include "util-time.h"

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

/* ------------------------------------------------------------ lock */

static void print_lock(const json_t *in)
{
	json_t *lock = json_object_get(in, "lock");

	if (!json_is_object(lock)) {
		printf("%s: not locked\n", str(in, "name"));
		return;
	}
	printf("%s: locked by %s since %s%s: %s\n", str(in, "name"), str(lock, "holder"),
	       str(lock, "since"), json_is_true(json_object_get(lock, "pause")) ? " (its job paused)"
									       : "", str(lock, "reason"));
}

int cmd_lock(struct ctl *ctl, int argc, char **argv)
{
	static const struct option opts[] = {
		{ "pause", no_argument, NULL, 'p' }, JSON_OPTION, HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	static const char usage[] = "lock INSTRUMENT REASON... [--pause] [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	_cleanup_free_ char *reason = NULL;
	bool pause = false;
	size_t len = 0;
	int c, r;

	while ((c = getopt_long(argc, argv, "pjh", opts, NULL)) != -1) {
		switch (c) {
		case 'p': pause = true; break;
		case 'j': ctl->json = true; break;
		case 'h': printf("Usage: asphctl %s\n", usage); return CTL_EXIT_OK;
		default: return usage_error(usage);
		}
	}
	if (argc - optind < 2)
		return usage_error(usage);
	/* The reason is the rest of the line, as typed. */
	for (int i = optind + 1; i < argc; i++)
		len += strlen(argv[i]) + 1;
	reason = calloc(1, len + 1);
	if (!reason)
		return CTL_EXIT_ERROR;
	for (int i = optind + 1; i < argc; i++) {
		if (i > optind + 1)
			strcat(reason, " ");
		strcat(reason, argv[i]);
	}
	r = ctl_call(ctl, "instrument.lock", json_pack("{s:s, s:s, s:b}", "name", argv[optind],
						       "reason", reason, "pause", pause), &result);
	if (r)
		return r;
	if (ctl->json)
		ctl_print_json(result);
	else
		print_lock(result);
	return CTL_EXIT_OK;
}

int cmd_unlock(struct ctl *ctl, int argc, char **argv)
{
	static const struct option opts[] = {
		{ "force", no_argument, NULL, 'f' }, JSON_OPTION, HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	static const char usage[] = "unlock INSTRUMENT [--force] [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	bool force = false;
	int c, r;

	while ((c = getopt_long(argc, argv, "fjh", opts, NULL)) != -1) {
		switch (c) {
		case 'f': force = true; break;
		case 'j': ctl->json = true; break;
		case 'h': printf("Usage: asphctl %s\n", usage); return CTL_EXIT_OK;
		default: return usage_error(usage);
		}
	}
	if (argc - optind != 1)
		return usage_error(usage);
	r = ctl_call(ctl, "instrument.unlock", json_pack("{s:s, s:b}", "name", argv[optind],
							 "force", force), &result);
	if (r)
		return r;
	if (ctl->json)
		ctl_print_json(result);
	else
		print_lock(result);
	return CTL_EXIT_OK;
}

/* ------------------------------------------------------------ token */

/*
 * --expires: a time from now ("90d", "12h", "30m", "45s") or a UTC day or
 * time as the daemon takes it ("2027-01-31", "2027-01-31T12:00:00Z"),
 * into the latter.
 */
static int expiry_param(const char *arg, char out[ISO8601_SIZE])
{
	static const struct { char unit; long long s; } units[] = {
		{ 's', 1 }, { 'm', 60 }, { 'h', 3600 }, { 'd', 86400 }, { 'w', 604800 },
	};
	size_t n = strlen(arg);
	int64_t at;
	long long v;
	char num[32];

	if (iso8601_parse_utc(arg, &at) == 0) {
		snprintf(out, ISO8601_SIZE, "%s", arg);
		return 0;
	}
	if (n < 2 || n >= sizeof(num))
		return -EINVAL;
	memcpy(num, arg, n - 1);
	num[n - 1] = '\0';
	for (size_t i = 0; i < ARRAY_SIZE(units); i++) {
		if (arg[n - 1] != units[i].unit)
			continue;
		if (ctl_parse_integer(num, 1, LLONG_MAX / units[i].s / NS_PER_SEC / 2, &v) < 0)
			return -EINVAL;
		iso8601_utc(now_realtime_ns() + (int64_t)(v * units[i].s) * NS_PER_SEC, 0, out,
			    ISO8601_SIZE);
		return 0;
	}
	return -EINVAL;
}

static int token_create(struct ctl *ctl, int argc, char **argv)
{
	static const struct option opts[] = {
		{ "role", required_argument, NULL, 'r' },
		{ "expires", required_argument, NULL, 'e' },
		JSON_OPTION, HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	static const char usage[] = "token create NAME --role viewer|operator|admin "
				    "[--expires 90d|12h|2027-01-31] [--json]";
	_cleanup_(json_decrefp) json_t *params = json_object();
	_cleanup_(json_decrefp) json_t *result = NULL;
	char when[ISO8601_SIZE];
	int c, r;

	while ((c = getopt_long(argc, argv, "r:e:jh", opts, NULL)) != -1) {
		switch (c) {
		case 'r': json_object_set_new(params, "role", json_string(optarg)); break;
		case 'e':
			if (expiry_param(optarg, when) < 0) {
				fprintf(stderr, "asphctl: --expires: '%s' is neither a time from now "
					"(90d, 12h, 30m, 45s, 2w) nor a UTC day or time (2027-01-31, "
					"2027-01-31T12:00:00Z)\n", optarg);
				return CTL_EXIT_USAGE;
			}
			json_object_set_new(params, "expires", json_string(when));
			break;
		case 'j': ctl->json = true; break;
		case 'h': printf("Usage: asphctl %s\n", usage); return CTL_EXIT_OK;
		default: return usage_error(usage);
		}
	}
	if (argc - optind != 1 || !json_object_get(params, "role"))
		return usage_error(usage);
	json_object_set_new(params, "name", json_string(argv[optind]));
	r = ctl_call(ctl, "token.create", json_incref(params), &result);
	if (r)
		return r;
	if (ctl->json) {
		ctl_print_json(result);
		return CTL_EXIT_OK;
	}
	printf("token %s (%s%s%s):\n%s\n", str(result, "name"), str(result, "role"),
	       json_is_string(json_object_get(result, "expires")) ? ", expires " : "",
	       json_is_string(json_object_get(result, "expires")) ? str(result, "expires") : "",
	       str(result, "token"));
	fprintf(stderr, "asphctl: this is the only time the token is shown: the daemon keeps "
		"only its hash\n");
	return CTL_EXIT_OK;
}

static int token_list(struct ctl *ctl)
{
	_cleanup_(json_decrefp) json_t *result = NULL;
	json_t *t;
	size_t i;
	int r = ctl_call(ctl, "token.list", NULL, &result);

	if (r)
		return r;
	if (ctl->json) {
		ctl_print_json(result);
		return CTL_EXIT_OK;
	}
	printf("%-24s %-9s %-8s %-21s %-21s %s\n", "NAME", "ROLE", "STATE", "CREATED", "EXPIRES",
	       "BY");
	json_array_foreach(json_object_get(result, "tokens"), i, t)
		printf("%-24s %-9s %-8s %-21s %-21s %s\n", str(t, "name"), str(t, "role"),
		       str(t, "state"), str(t, "created"), str(t, "expires"), str(t, "created_by"));
	return CTL_EXIT_OK;
}

static int token_revoke(struct ctl *ctl, const char *name)
{
	_cleanup_(json_decrefp) json_t *result = NULL;
	int r = ctl_call(ctl, "token.revoke", json_pack("{s:s}", "name", name), &result);

	if (r)
		return r;
	if (ctl->json)
		ctl_print_json(result);
	else
		printf("token %s revoked; its connections are closed\n", name);
	return CTL_EXIT_OK;
}

int cmd_token(struct ctl *ctl, int argc, char **argv)
{
	static const char usage[] = "token create NAME --role viewer|operator|admin [--expires WHEN]\n"
				    "       token list [--json]\n"
				    "       token revoke NAME [--json]";
	static const struct option opts[] = { JSON_OPTION, HELP_OPTION, { NULL, 0, NULL, 0 } };
	int c;

	if (argc >= 2 && !strcmp(argv[1], "create"))
		return token_create(ctl, argc - 1, argv + 1);
	while ((c = getopt_long(argc, argv, "jh", opts, NULL)) != -1) {
		switch (c) {
		case 'j': ctl->json = true; break;
		case 'h': printf("Usage: asphctl %s\n", usage); return CTL_EXIT_OK;
		default: return usage_error(usage);
		}
	}
	if (argc - optind == 1 && !strcmp(argv[optind], "list"))
		return token_list(ctl);
	if (argc - optind == 2 && !strcmp(argv[optind], "revoke"))
		return token_revoke(ctl, argv[optind + 1]);
	return usage_error(usage);
}
