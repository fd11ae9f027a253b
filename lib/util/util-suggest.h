/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * "Did you mean ...?": the name closest to a mistyped one, among the names
 * a table defines (commands, options, presets, plan methods, driver
 * options). The caller offers each candidate from its table in turn; the
 * closest one within reach wins. Shared by asph, asphctl, asphd, the
 * drivers and libasph. Internal header.
 */
#ifndef ASPH_UTIL_SUGGEST_H
#define ASPH_UTIL_SUGGEST_H

#include <stddef.h>

/*
 * The optimal string alignment distance between a and b: insertions,
 * deletions, substitutions and swaps of two neighbours, each counting 1,
 * letters compared without case. Names longer than SUGGEST_MAX_LEN bytes
 * count as infinitely far (SIZE_MAX).
 */
#define SUGGEST_MAX_LEN 64
size_t suggest_distance(const char *a, const char *b);

struct suggest {
	const char *word;       /* what was typed */
	const char *best;       /* the closest candidate within reach, or NULL */
	size_t distance;
};

void suggest_init(struct suggest *s, const char *word);
/* Offers one candidate (NULL is ignored). A candidate is within reach when
 * at most a third of the typed word (at least one edit) has to change, or
 * when the typed word is a prefix of it (three letters at least); of
 * equally close ones the first offered stays. */
void suggest_offer(struct suggest *s, const char *candidate);
/* The candidate to suggest, or NULL. */
const char *suggest_best(const struct suggest *s);

/*
 * " (did you mean 'BEST'?)" into buf when there is one, else "": for
 * messages such as "unknown method 'cvtt'%s". Returns buf.
 */
const char *suggest_hint(const struct suggest *s, char *buf, size_t size);

/* The same over a NULL-terminated list of names. */
const char *suggest_from_list(const char *word, const char *const *names);

/*
 * A table's names[0, n) for a message or a help text, NULL ones left out:
 * ", " between them, and last (", " or " or ") before the last one
 * ("conformal, xy or plan-mesh"), into buf as snprintf() writes. Returns
 * the length of the whole list.
 */
int suggest_join(char *buf, size_t size, const char *const *names, size_t n, const char *last);

/*
 * What was wrong with the option getopt_long() just refused (it returned
 * '?' or ':', with opterr = 0), read from argv, optind and optopt as
 * getopt_long() left them, into buf: "unknown option '--tolerence' (did
 * you mean '--tolerance'?)", "option '--tolerance' needs a value", "option
 * '--robust' takes no value", "option '--c' is ambiguous: --correction,
 * --correction-kind, ...", "unknown option '-x'", "option '-o' needs a
 * value" (shortopts: getopt_long()'s). Returns buf.
 */
struct option;
const char *suggest_getopt_error(char **argv, const char *shortopts,
				 const struct option *longopts, char *buf, size_t size);

#endif
