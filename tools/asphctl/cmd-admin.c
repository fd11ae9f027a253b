/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asphctl lock, unlock, token, fleet. */
#include <errno.h>
#include <getopt.h>
#include <limits.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <libpq-fe.h>

#include "asph-names.h"
#include "asphctl.h"
#include "util-mem.h"
#include "util-suggest.h"
#include "util-time.h"

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
	static const char usage[] = "lock INSTRUMENT REASON... [--pause] [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	_cleanup_free_ char *reason = NULL;
	bool pause = false;
	size_t len = 0;
	int c, r;

	if ((c = ctl_flag_option(ctl, argc, argv, "pause", 'p', &pause, usage)) >= 0)
		return c;
	if (argc - optind < 2)
		return ctl_usage_error(usage);
	/* The reason is the rest of the line, as typed. */
	for (int i = optind + 1; i < argc; i++)
		len += strlen(argv[i]) + 1;
	reason = calloc(1, len + 1);
	if (!reason)
		return EXIT_FAILURE_RUN;
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
	return EXIT_OK;
}

int cmd_unlock(struct ctl *ctl, int argc, char **argv)
{
	static const char usage[] = "unlock INSTRUMENT [--force] [--json]";
	_cleanup_(json_decrefp) json_t *result = NULL;
	bool force = false;
	int c, r;

	if ((c = ctl_flag_option(ctl, argc, argv, "force", 'f', &force, usage)) >= 0)
		return c;
	if (argc - optind != 1)
		return ctl_usage_error(usage);
	r = ctl_call(ctl, "instrument.unlock", json_pack("{s:s, s:b}", "name", argv[optind],
							 "force", force), &result);
	if (r)
		return r;
	if (ctl->json)
		ctl_print_json(result);
	else
		print_lock(result);
	return EXIT_OK;
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
		CTL_JSON_OPTION, CTL_HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	static const char usage[] = "token create NAME --role viewer|operator|admin "
				    "[--expires 90d|12h|2027-01-31] [--json]";
	_cleanup_(json_decrefp) json_t *params = json_object();
	_cleanup_(json_decrefp) json_t *result = NULL;
	char when[ISO8601_SIZE];
	int c, r;

	while ((c = ctl_option(ctl, argc, argv, "r:e:", opts, usage)) > 0) {
		switch (c) {
		case 'r': json_object_set_new(params, "role", json_string(optarg)); break;
		case 'e':
			if (expiry_param(optarg, when) < 0) {
				fprintf(stderr, "asphctl: --expires: '%s' is neither a time from now "
					"(90d, 12h, 30m, 45s, 2w) nor a UTC day or time (2027-01-31, "
					"2027-01-31T12:00:00Z)\n", optarg);
				return EXIT_USAGE;
			}
			json_object_set_new(params, "expires", json_string(when));
			break;
		}
	}
	if (c != CTL_OPTIONS_END)
		return ctl_options_exit(c);
	if (argc - optind != 1 || !json_object_get(params, "role"))
		return ctl_usage_error(usage);
	json_object_set_new(params, "name", json_string(argv[optind]));
	r = ctl_call(ctl, "token.create", json_incref(params), &result);
	if (r)
		return r;
	if (ctl->json) {
		ctl_print_json(result);
		return EXIT_OK;
	}
	printf("token %s (%s%s%s):\n%s\n", str(result, "name"), str(result, "role"),
	       json_is_string(json_object_get(result, "expires")) ? ", expires " : "",
	       json_is_string(json_object_get(result, "expires")) ? str(result, "expires") : "",
	       str(result, "token"));
	fprintf(stderr, "asphctl: this is the only time the token is shown: the daemon keeps "
		"only its hash\n");
	return EXIT_OK;
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
		return EXIT_OK;
	}
	printf("%-24s %-9s %-8s %-21s %-21s %s\n", "NAME", "ROLE", "STATE", "CREATED", "EXPIRES",
	       "BY");
	json_array_foreach(json_object_get(result, "tokens"), i, t)
		printf("%-24s %-9s %-8s %-21s %-21s %s\n", str(t, "name"), str(t, "role"),
		       str(t, "state"), str(t, "created"), str(t, "expires"), str(t, "created_by"));
	return EXIT_OK;
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
	return EXIT_OK;
}

int cmd_token(struct ctl *ctl, int argc, char **argv)
{
	static const char usage[] = "token create NAME --role viewer|operator|admin [--expires WHEN]\n"
				    "       token list [--json]\n"
				    "       token revoke NAME [--json]";
	int c;

	if (argc >= 2 && !strcmp(argv[1], "create"))
		return token_create(ctl, argc - 1, argv + 1);
	if ((c = ctl_common_options(ctl, argc, argv, usage)) >= 0)
		return c;
	if (argc - optind == 1 && !strcmp(argv[optind], "list"))
		return token_list(ctl);
	if (argc - optind == 2 && !strcmp(argv[optind], "revoke"))
		return token_revoke(ctl, argv[optind + 1]);
	return ctl_usage_error(usage);
}

/* ------------------------------------------------------------ fleet */

/* The newest results across daemons, from the view of docs/fleet.md. */
static const char fleet_query[] =
	"SELECT to_char(finished_at AT TIME ZONE 'UTC', 'YYYY-MM-DD\"T\"HH24:MI:SS\"Z\"'), host,"
	" instrument, job_id, state, verdict, part, lot, serial, label, rms_nm, pv_nm,"
	" submitted_by, daemon_id"
	" FROM asphd.fleet_results"
	" WHERE ($1::text IS NULL OR host = $1) AND ($2::text IS NULL OR part = $2)"
	" AND ($3::text IS NULL OR lot = $3) AND ($4::text IS NULL OR serial = $4)"
	" AND ($5::text IS NULL OR verdict = $5)"
	" ORDER BY finished_at DESC, host, job_id DESC LIMIT $6::bigint";

static const char *const fleet_columns[] = {
	"finished", "host", "instrument", "job", "state", "verdict", "part", "lot", "serial",
	"label", "rms_nm", "pv_nm", "submitted_by", "daemon",
};

static json_t *fleet_json(const PGresult *res)
{
	json_t *rows = json_array();

	for (int i = 0; rows && i < PQntuples(res); i++) {
		json_t *o = json_object();
		for (int k = 0; k < (int)ARRAY_SIZE(fleet_columns); k++) {
			const char *v = PQgetisnull(res, i, k) ? NULL : PQgetvalue(res, i, k);
			json_t *j = !v ? json_null()
				  : k == 3 ? json_integer(strtoll(v, NULL, 10))
				  : k == 10 || k == 11 ? json_real(strtod(v, NULL)) : json_string(v);
			json_object_set_new(o, fleet_columns[k], j);
		}
		json_array_append_new(rows, o);
	}
	return json_pack("{s:o}", "results", rows);
}

static void fleet_print(const PGresult *res)
{
	printf("%-20s %-16s %-10s %6s %-9s %-9s %-12s %-10s %-10s %9s\n", "FINISHED", "HOST",
	       "INSTRUMENT", "JOB", "STATE", "VERDICT", "PART", "LOT", "SERIAL", "RMS_NM");
	for (int i = 0; i < PQntuples(res); i++) {
		_cleanup_free_ char *host = ctl_escape(PQgetvalue(res, i, 1), false);
		_cleanup_free_ char *part = ctl_escape(PQgetvalue(res, i, 6), false);
		_cleanup_free_ char *lot = ctl_escape(PQgetvalue(res, i, 7), false);
		_cleanup_free_ char *serial = ctl_escape(PQgetvalue(res, i, 8), false);
		printf("%-20s %-16s %-10s %6s %-9s %-9s %-12s %-10s %-10s %9s\n", PQgetvalue(res, i, 0),
		       host ? host : "", PQgetvalue(res, i, 2), PQgetvalue(res, i, 3),
		       PQgetvalue(res, i, 4), PQgetisnull(res, i, 5) ? "-" : PQgetvalue(res, i, 5),
		       PQgetisnull(res, i, 6) ? "-" : part, PQgetisnull(res, i, 7) ? "-" : lot,
		       PQgetisnull(res, i, 8) ? "-" : serial,
		       PQgetisnull(res, i, 10) ? "-" : PQgetvalue(res, i, 10));
	}
	printf("(%d result(s))\n", PQntuples(res));
}

/* --verdict: one of libasph's verdicts (print-names); false after saying
 * so. */
static bool is_verdict(const char *arg)
{
	static const char *const verdicts[] = { NAMES_VERDICT_LIST };
	char known[64];

	for (size_t i = 0; i < ARRAY_SIZE(verdicts); i++)
		if (!strcmp(arg, verdicts[i]))
			return true;
	suggest_join(known, sizeof(known), verdicts, ARRAY_SIZE(verdicts), " or ");
	fprintf(stderr, "asphctl: --verdict: '%s' is not %s\n", arg, known);
	return false;
}

int cmd_fleet(struct ctl *ctl, int argc, char **argv)
{
	static const struct option opts[] = {
		{ "db", required_argument, NULL, 'd' },
		{ "limit", required_argument, NULL, 'n' },
		{ "host", required_argument, NULL, 'H' },
		{ "part", required_argument, NULL, 'A' },
		{ "lot", required_argument, NULL, 'L' },
		{ "serial", required_argument, NULL, 'N' },
		{ "verdict", required_argument, NULL, 'v' },
		CTL_JSON_OPTION, CTL_HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	static const char usage[] = "fleet list [--db CONNINFO] [--limit N] [--host H] [--part P]\n"
				    "       [--lot L] [--serial S] [--verdict pass|fail|undecided] [--json]";
	const char *params[6] = { NULL, NULL, NULL, NULL, NULL, "50" };
	const char *conninfo = getenv("ASPHCTL_FLEET_DB");
	long long limit;
	PGconn *db;
	PGresult *res;
	int c, rc = EXIT_OK;

	while ((c = ctl_option(ctl, argc, argv, "d:n:", opts, usage)) > 0) {
		switch (c) {
		case 'd': conninfo = optarg; break;
		case 'n':
			if (ctl_parse_integer(optarg, 1, 100000, &limit) < 0) {
				fprintf(stderr, "asphctl: --limit: '%s' is not a count from 1 to "
					"100000\n", optarg);
				return EXIT_USAGE;
			}
			params[5] = optarg;
			break;
		case 'H': params[0] = optarg; break;
		case 'A': params[1] = optarg; break;
		case 'L': params[2] = optarg; break;
		case 'N': params[3] = optarg; break;
		case 'v':
			if (!is_verdict(optarg))
				return EXIT_USAGE;
			params[4] = optarg;
			break;
		}
	}
	if (c != CTL_OPTIONS_END)
		return ctl_options_exit(c);
	if (argc - optind != 1 || strcmp(argv[optind], "list"))
		return ctl_usage_error(usage);
	/* Without --db or ASPHCTL_FLEET_DB, libpq's own (PGHOST, ~/.pgpass, ...). */
	db = PQconnectdbParams((const char *const[]){ "dbname", "application_name", NULL },
			       (const char *const[]){ conninfo ? conninfo : "", "asphctl", NULL }, 1);
	if (PQstatus(db) != CONNECTION_OK) {
		fprintf(stderr, "asphctl: cannot connect to the fleet's database: %s",
			PQerrorMessage(db));
		PQfinish(db);
		return EXIT_UNREACHABLE;
	}
	res = PQexecParams(db, fleet_query, 6, NULL, params, NULL, NULL, 0);
	if (PQresultStatus(res) != PGRES_TUPLES_OK) {
		fprintf(stderr, "asphctl: %s", PQerrorMessage(db));
		rc = EXIT_FAILURE_RUN;
	} else if (ctl->json) {
		json_t *j = fleet_json(res);
		ctl_print_json(j);
		json_decref(j);
	} else {
		fleet_print(res);
	}
	PQclear(res);
	PQfinish(db);
	return rc;
}
