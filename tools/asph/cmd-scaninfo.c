/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <getopt.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph/scanfile.h"
#include "asph-tool.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile_reader *, asph_scanfile_reader_free)

#define N_FLAGS 6

/* What the points say, gathered block by block. */
struct scan_stats {
	uint64_t n;
	uint64_t index_min, index_max;
	uint64_t t_first, t_last;
	uint64_t flags[N_FLAGS];
	uint64_t sources[ASPH_SCANFILE_POSITION_COMMANDED + 1];
};

static void stats_add(struct scan_stats *st, const struct asph_scanfile_point *p, size_t n)
{
	for (size_t i = 0; i < n; i++, st->n++) {
		if (st->n == 0 || p[i].plan_index < st->index_min)
			st->index_min = p[i].plan_index;
		if (st->n == 0 || p[i].plan_index > st->index_max)
			st->index_max = p[i].plan_index;
		if (st->n == 0)
			st->t_first = p[i].t_ns;
		st->t_last = p[i].t_ns;
		for (int b = 0; b < N_FLAGS; b++)
			st->flags[b] += (p[i].flags >> b) & 1;
		if (p[i].position_source <= ASPH_SCANFILE_POSITION_COMMANDED)
			st->sources[p[i].position_source]++;
	}
}

static double duration_s(const struct scan_stats *st)
{
	return st->n && st->t_last > st->t_first ? (double)(st->t_last - st->t_first) * 1e-9 : 0;
}

static json_t *member_json(const char *text)
{
	json_t *v = json_loads(text, 0, NULL);
	return v ? v : json_null();
}

static json_t *flags_json(const struct scan_stats *st)
{
	json_t *o = json_object();
	for (int b = 0; b < N_FLAGS; b++)
		json_object_set_new(o, asph_scanfile_flag_name(1u << b),
				    json_integer((json_int_t)st->flags[b]));
	return o;
}

static json_t *sources_json(const struct scan_stats *st)
{
	json_t *o = json_object();
	for (uint32_t k = 0; k <= ASPH_SCANFILE_POSITION_COMMANDED; k++)
		json_object_set_new(o, asph_scanfile_position_source_name(k),
				    json_integer((json_int_t)st->sources[k]));
	return o;
}

static json_t *recovery_json(const struct asph_scanfile_report *rep)
{
	return json_pack("{s:s, s:I, s:s, s:I, s:I, s:I}",
			 "stop", asph_scanfile_stop_name(rep->stop),
			 "stop_offset", (json_int_t)rep->stop_offset,
			 "detail", rep->stop_detail,
			 "file_bytes", (json_int_t)rep->file_size,
			 "valid_bytes", (json_int_t)rep->valid_bytes,
			 "discarded_bytes", (json_int_t)rep->discarded_bytes);
}

static int show_json(const char *path, const struct asph_scanfile_reader *r,
		     const struct scan_stats *st)
{
	const struct asph_scanfile_header *h = asph_scanfile_reader_header(r);
	const struct asph_scanfile_report *rep = asph_scanfile_reader_report(r);
	const char *const *ev;
	size_t n_ev = asph_scanfile_reader_events(r, &ev);
	char version[32];

	snprintf(version, sizeof(version), "%u.%u", h->version_major, h->version_minor);
	_cleanup_(json_decrefp) json_t *root = json_pack(
		"{s:s, s:s, s:s, s:s, s:I, s:o, s:o, s:o, s:o, s:I, s:I, s:o, s:f, s:o, s:b, s:s, s:o, s:I, s:o}",
		"file", path, "format_version", version, "software_version", h->software_version,
		"created", h->created, "created_ns", (json_int_t)h->created_ns,
		"prescription", member_json(h->prescription), "plan", member_json(h->plan),
		"instrument", member_json(h->instrument), "metadata", member_json(h->metadata),
		"points", (json_int_t)st->n, "blocks", (json_int_t)rep->n_blocks,
		"plan_index", st->n ? json_pack("{s:I, s:I}", "min", (json_int_t)st->index_min,
						"max", (json_int_t)st->index_max) : json_null(),
		"duration_s", duration_s(st), "flags", flags_json(st),
		"ended", rep->ended, "outcome", asph_scanfile_outcome_name(rep->outcome),
		"reason", rep->reason ? json_string(rep->reason) : json_null(),
		"resumes", (json_int_t)rep->n_resumes, "recovery", recovery_json(rep));
	if (!root)
		return EXIT_FAILURE_RUN;
	json_t *events = json_array();
	for (size_t i = 0; i < n_ev; i++)
		json_array_append_new(events, member_json(ev[i]));
	json_object_set_new(root, "events", events);
	json_object_set_new(root, "positions", sources_json(st));
	json_object_set_new(root, "references", json_integer((json_int_t)rep->n_references));
	json_dumpf(root, stdout, JSON_INDENT(2) | JSON_REAL_PRECISION(17));
	fputc('\n', stdout);
	return EXIT_OK;
}

static void show_recovery(const struct asph_scanfile_report *rep)
{
	if (rep->stop == ASPH_SCANFILE_STOP_END) {
		printf("Recovery        all %" PRIu64 " bytes valid\n", rep->valid_bytes);
		return;
	}
	printf("Recovery        kept %" PRIu64 " of %" PRIu64 " bytes, discarded %" PRIu64
	       " (%s: %s)\n", rep->valid_bytes, rep->file_size, rep->discarded_bytes,
	       asph_scanfile_stop_name(rep->stop), rep->stop_detail);
}

static void show_text(const char *path, const struct asph_scanfile_reader *r,
		      const struct scan_stats *st)
{
	const struct asph_scanfile_header *h = asph_scanfile_reader_header(r);
	const struct asph_scanfile_report *rep = asph_scanfile_reader_report(r);

	printf("Scan            %s\n", path);
	printf("Format          %u.%u, written by libasph %s\n", h->version_major,
	       h->version_minor, h->software_version);
	printf("Created         %s\n", h->created);
	printf("Points          %" PRIu64 " in %" PRIu64 " blocks\n", st->n, rep->n_blocks);
	for (int b = 0; b < N_FLAGS; b++)
		if (st->flags[b])
			printf("  %-18s%" PRIu64 "\n", asph_scanfile_flag_name(1u << b), st->flags[b]);
	printf("Positions      ");
	for (uint32_t k = 0; k <= ASPH_SCANFILE_POSITION_COMMANDED; k++)
		if (st->sources[k])
			printf(" %" PRIu64 " %s", st->sources[k], asph_scanfile_position_source_name(k));
	printf("%s\n", st->n ? "" : " none");
	if (rep->n_references)
		printf("References      %" PRIu64 " measurements of drift references\n",
		       rep->n_references);
	if (st->n)
		printf("Plan indices    %" PRIu64 " .. %" PRIu64 "\n", st->index_min, st->index_max);
	printf("Duration        %.3f s (first to last point)\n", duration_s(st));
	if (rep->ended)
		printf("Outcome         %s%s%s\n", asph_scanfile_outcome_name(rep->outcome),
		       rep->reason ? ": " : "", rep->reason ? rep->reason : "");
	else
		printf("Outcome         unfinished (no end block: the scan was cut off)\n");
	if (rep->n_resumes)
		printf("Resumed         %u time%s\n", rep->n_resumes, rep->n_resumes > 1 ? "s" : "");
	show_recovery(rep);
	printf("Prescription    %s\n", h->prescription);
	printf("Plan            %s\n", h->plan);
	printf("Instrument      %s\n", h->instrument);
	printf("Metadata        %s\n", h->metadata);
}

static void usage(FILE *out)
{
	fprintf(out, "Usage: asph scaninfo SCAN [--json]\n\n"
		     "Shows a recorded scan: its header (lens, plan, instrument, metadata), the\n"
		     "points it holds, how it ended, and what reading it recovered.\n"
		     "  --json   print one JSON object\n");
}

int cmd_scaninfo(int argc, char **argv)
{
	static const struct option options[] = {
		{ "json", no_argument, NULL, 'j' },
		{ "help", no_argument, NULL, 'h' },
		{ 0 }
	};
	int json = 0;
	int code = tool_getopt(argc, argv, "h", options, usage, tool_take_flag, &json);

	if (code >= 0)
		return code;
	if (optind + 1 != argc) {
		usage(stderr);
		return EXIT_USAGE;
	}

	const char *path = argv[optind];
	_cleanup_(asph_scanfile_reader_freep) struct asph_scanfile_reader *r = NULL;
	struct scan_stats st = { 0 };
	const struct asph_scanfile_point *pts;
	struct asph_error err;
	size_t n;
	int ret;

	asph_error_clear(&err);
	if (asph_scanfile_reader_open(path, &r, &err) < 0) {
		tool_print_error(NULL, &err);
		return EXIT_FAILURE_RUN;
	}
	while ((ret = asph_scanfile_reader_next(r, &pts, &n, &err)) > 0)
		stats_add(&st, pts, n);
	if (ret < 0) {
		tool_print_error(NULL, &err);
		return EXIT_FAILURE_RUN;
	}
	if (json)
		return show_json(path, r, &st);
	show_text(path, r, &st);
	return EXIT_OK;
}
