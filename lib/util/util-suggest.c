/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <ctype.h>
#include <getopt.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>

#include "util-suggest.h"

static int same_letter(char a, char b)
{
	return tolower((unsigned char)a) == tolower((unsigned char)b);
}

static size_t min3(size_t a, size_t b, size_t c)
{
	size_t m = a < b ? a : b;

	return m < c ? m : c;
}

size_t suggest_distance(const char *a, const char *b)
{
	size_t la = strlen(a), lb = strlen(b);
	size_t d[SUGGEST_MAX_LEN + 1][SUGGEST_MAX_LEN + 1];

	if (la > SUGGEST_MAX_LEN || lb > SUGGEST_MAX_LEN)
		return SIZE_MAX;
	for (size_t i = 0; i <= la; i++)
		d[i][0] = i;
	for (size_t j = 0; j <= lb; j++)
		d[0][j] = j;
	for (size_t i = 1; i <= la; i++) {
		for (size_t j = 1; j <= lb; j++) {
			size_t cost = same_letter(a[i - 1], b[j - 1]) ? 0 : 1;

			d[i][j] = min3(d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + cost);
			/* two neighbours swapped ("stauts") */
			if (i > 1 && j > 1 && same_letter(a[i - 1], b[j - 2]) &&
			    same_letter(a[i - 2], b[j - 1]) && d[i - 2][j - 2] + 1 < d[i][j])
				d[i][j] = d[i - 2][j - 2] + 1;
		}
	}
	return d[la][lb];
}

void suggest_init(struct suggest *s, const char *word)
{
	*s = (struct suggest){ .word = word, .distance = SIZE_MAX };
}

/* Within reach: a third of the word may change (one edit at least), so
 * "cvtt" finds "cvt" and "op" does not become "lb". */
static size_t reach(const char *word)
{
	size_t n = strlen(word) / 3;

	return n ? n : 1;
}

static int is_prefix(const char *word, const char *candidate)
{
	size_t n = strlen(word);

	return n >= 3 && n < strlen(candidate) && !strncasecmp(word, candidate, n);
}

void suggest_offer(struct suggest *s, const char *candidate)
{
	size_t d;

	if (!candidate || !s->word || !*s->word || !strcmp(candidate, s->word))
		return;
	d = suggest_distance(s->word, candidate);
	if (d > reach(s->word) && !is_prefix(s->word, candidate))
		return;
	/* a prefix counts as one edit away: "tol" -> "tolerance" */
	if (d > reach(s->word))
		d = reach(s->word);
	if (d < s->distance) {
		s->best = candidate;
		s->distance = d;
	}
}

const char *suggest_best(const struct suggest *s)
{
	return s->best;
}

const char *suggest_hint(const struct suggest *s, char *buf, size_t size)
{
	if (!size)
		return buf;
	if (s->best)
		snprintf(buf, size, " (did you mean '%s'?)", s->best);
	else
		buf[0] = '\0';
	return buf;
}

const char *suggest_from_list(const char *word, const char *const *names)
{
	struct suggest s;

	suggest_init(&s, word);
	for (; names && *names; names++)
		suggest_offer(&s, *names);
	return suggest_best(&s);
}

/* "--name=value" -> "name" into buf. */
static const char *long_name(const char *arg, char *buf, size_t size)
{
	size_t n = strcspn(arg + 2, "=");

	snprintf(buf, size, "%.*s", (int)n, arg + 2);
	return buf;
}

/* The long options whose name starts with name: how many, and the first
 * (the one named exactly, when one is). */
static const struct option *long_match(const struct option *longopts, const char *name,
				       size_t *count)
{
	const struct option *first = NULL;
	size_t n = strlen(name);

	*count = 0;
	for (const struct option *o = longopts; o && o->name; o++) {
		if (!strcmp(o->name, name)) {
			*count = 1;
			return o;
		}
		if (!strncmp(o->name, name, n)) {
			if (!first)
				first = o;
			++*count;
		}
	}
	return first;
}

static const char *ambiguous(const struct option *longopts, const char *name, char *buf,
			     size_t size)
{
	size_t n = strlen(name), used;

	used = (size_t)snprintf(buf, size, "option '--%s' is ambiguous:", name);
	for (const struct option *o = longopts; o->name && used < size; o++)
		if (!strncmp(o->name, name, n))
			used += (size_t)snprintf(buf + used, size - used, " --%s", o->name);
	return buf;
}

static const char *short_error(const char *shortopts, char *buf, size_t size)
{
	const char *at = optopt > 0 && optopt < 128 && optopt != ':' ? strchr(shortopts, optopt)
								       : NULL;

	if (at)
		snprintf(buf, size, "option '-%c' needs a value", optopt);
	else if (optopt > 0 && optopt < 128 && isprint(optopt))
		snprintf(buf, size, "unknown option '-%c'", optopt);
	else
		snprintf(buf, size, "unknown option");
	return buf;
}

const char *suggest_getopt_error(char **argv, const char *shortopts,
				 const struct option *longopts, char *buf, size_t size)
{
	const char *arg = optind > 0 ? argv[optind - 1] : NULL;
	const struct option *o;
	char name[SUGGEST_MAX_LEN + 1], hint[SUGGEST_MAX_LEN + 32];
	struct suggest s;
	size_t count;

	/* A short option (alone or in a cluster such as -xq) has optopt set
	 * to its letter and no "--" element behind it naming that option. */
	if (!arg || strncmp(arg, "--", 2) || !arg[2])
		return short_error(shortopts, buf, size);
	long_name(arg, name, sizeof(name));
	o = long_match(longopts, name, &count);
	if (count > 1)
		return ambiguous(longopts, name, buf, size);
	if (o && optopt && o->val == optopt) {
		snprintf(buf, size, o->has_arg == no_argument ? "option '--%s' takes no value"
							      : "option '--%s' needs a value", o->name);
		return buf;
	}
	if (o)  /* getopt_long() knew it: a short option after it was wrong */
		return short_error(shortopts, buf, size);
	suggest_init(&s, name);
	for (o = longopts; o && o->name; o++)
		suggest_offer(&s, o->name);
	if (s.best)
		snprintf(hint, sizeof(hint), " (did you mean '--%s'?)", s.best);
	else
		hint[0] = '\0';
	snprintf(buf, size, "unknown option '--%s'%s", name, hint);
	return buf;
}

int suggest_join(char *buf, size_t size, const char *const *names, size_t n, const char *last)
{
	size_t len = 0, left = 0;

	if (size)
		buf[0] = '\0';
	for (size_t i = 0; i < n; i++)
		left += names[i] != NULL;
	for (size_t i = 0; i < n; i++) {
		if (!names[i])
			continue;
		const char *sep = len == 0 ? "" : left == 1 ? last : ", ";
		len += (size_t)snprintf(len < size ? buf + len : NULL, len < size ? size - len : 0,
					"%s%s", sep, names[i]);
		left--;
	}
	return (int)len;
}
