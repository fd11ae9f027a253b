/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Driver option values, checked against the driver's descriptors. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "options-internal.h"
#include "util-mem.h"
#include "util-suggest.h"

struct asph_options {
	const struct asph_driver *drv;
	struct asph_option_value *values;
	char **texts;           /* owned copies behind string values */
};

static int refuse(const struct asph_option_desc *d, int code,
		  struct asph_error *err, const char *what, const char *text)
{
	return asph_error_set_at(err, code, NULL, 0, 0, d->name, "option '%s': %s '%s'", d->name,
				 what, text);
}

static int parse_bool(const char *t, bool *out)
{
	static const char *const yes[] = { "true", "yes", "on", "1" };
	static const char *const no[] = { "false", "no", "off", "0" };

	for (size_t i = 0; i < ARRAY_SIZE(yes); i++) {
		if (!strcasecmp(t, yes[i]))
			return *out = true, 0;
		if (!strcasecmp(t, no[i]))
			return *out = false, 0;
	}
	return -EINVAL;
}

static int check_range(const struct asph_option_desc *d, double x,
		       const char *text, struct asph_error *err)
{
	if (!d->ranged || (x >= d->min && x <= d->max))
		return 0;
	return asph_error_set_at(err, -ERANGE, NULL, 0, 0, d->name,
				 "option '%s': %s is outside %.10g..%.10g%s%s", d->name, text,
				 d->min, d->max, d->unit ? " " : "", d->unit ? d->unit : "");
}

static int parse_enum(const struct asph_option_desc *d, const char *text,
		      struct asph_option_value *v, struct asph_error *err)
{
	char list[256] = "";

	for (size_t i = 0; d->choices && d->choices[i]; i++) {
		if (!strcmp(text, d->choices[i])) {
			v->i = (int64_t)i;
			v->s = d->choices[i];
			return 0;
		}
		size_t used = strlen(list);
		snprintf(list + used, sizeof(list) - used, "%s%s", i ? ", " : "",
			 d->choices[i]);
	}
	return asph_error_set_at(err, -ERANGE, NULL, 0, 0, d->name,
				 "option '%s': '%s' is not one of %s", d->name, text, list);
}

int option_parse(const struct asph_option_desc *d, const char *text,
		 struct asph_option_value *v, struct asph_error *err)
{
	char *end = NULL;

	v->type = d->type;
	switch (d->type) {
	case ASPH_OPTION_BOOL:
		if (parse_bool(text, &v->b) < 0)
			return refuse(d, -EINVAL, err, "expects true or false, not", text);
		return 0;
	case ASPH_OPTION_INT:
		errno = 0;
		/* 0x... for USB and HID ids as datasheets print them; no octal,
		 * so a leading zero never changes a decimal value. */
		v->i = strtoll(text, &end,
			       text[0] == '0' && (text[1] == 'x' || text[1] == 'X') ? 16 : 10);
		if (!*text || *end || errno)
			return refuse(d, -EINVAL, err, "expects an integer, not", text);
		v->d = (double)v->i;
		return check_range(d, v->d, text, err);
	case ASPH_OPTION_DOUBLE:
		errno = 0;
		v->d = strtod(text, &end);
		if (!*text || *end || errno || !isfinite(v->d))
			return refuse(d, -EINVAL, err, "expects a finite number, not", text);
		return check_range(d, v->d, text, err);
	case ASPH_OPTION_STRING:
		v->s = text;
		return 0;
	case ASPH_OPTION_ENUM:
		return parse_enum(d, text, v, err);
	}
	return refuse(d, -EINVAL, err, "has an unknown type for", text);
}

int option_desc_validate(const struct asph_option_desc *d,
			 struct asph_error *err)
{
	struct asph_option_value v = { 0 };
	bool name_ok = d->name && *d->name;

	for (const char *c = name_ok ? d->name : ""; *c; c++)
		if (!((*c >= 'a' && *c <= 'z') || (*c >= '0' && *c <= '9') || *c == '_'))
			name_ok = false;
	if (!name_ok)
		return asph_error_set(err, -EINVAL, "option name '%s' is not valid ([a-z0-9_]+)",
				      d->name ? d->name : "(null)");
	if (d->type > ASPH_OPTION_ENUM || (d->type == ASPH_OPTION_ENUM && !d->choices))
		return asph_error_set(err, -EINVAL, "option '%s': type not valid", d->name);
	if (d->ranged && !(d->min <= d->max))
		return asph_error_set(err, -EINVAL, "option '%s': range not valid", d->name);
	if (!d->default_value || !d->help)
		return asph_error_set(err, -EINVAL, "option '%s': default or help missing",
				      d->name);
	int r = option_parse(d, d->default_value, &v, err);
	if (r < 0)
		return asph_error_set(err, r, "option '%s': default '%s' does not parse",
				      d->name, d->default_value);
	return 0;
}

int asph_option_index(const struct asph_driver *drv, const char *name)
{
	for (size_t i = 0; i < drv->n_options; i++)
		if (!strcmp(drv->options[i].name, name))
			return (int)i;
	return -1;
}

const char *option_hint(const struct asph_driver *drv, const char *name, char *buf,
			size_t size)
{
	struct suggest s;

	suggest_init(&s, name);
	for (size_t i = 0; i < drv->n_options; i++)
		suggest_offer(&s, drv->options[i].name);
	return suggest_hint(&s, buf, size);
}

void asph_options_free(struct asph_options *o)
{
	if (!o)
		return;
	for (size_t i = 0; o->texts && i < o->drv->n_options; i++)
		free(o->texts[i]);
	free(o->texts);
	free(o->values);
	free(o);
}

int asph_options_new(const struct asph_driver *drv, struct asph_options **out,
		     struct asph_error *err)
{
	struct asph_options *o = calloc(1, sizeof(*o));
	size_t n = drv->n_options ? drv->n_options : 1;

	if (!o)
		return asph_error_set(err, -ENOMEM, "out of memory");
	o->drv = drv;
	o->values = calloc(n, sizeof(*o->values));
	o->texts = calloc(n, sizeof(*o->texts));
	if (!o->values || !o->texts) {
		asph_options_free(o);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	for (size_t i = 0; i < drv->n_options; i++) {
		int r = option_parse(&drv->options[i], drv->options[i].default_value,
				     &o->values[i], err);
		if (r < 0) {
			asph_options_free(o);
			return r;
		}
	}
	*out = o;
	return 0;
}

/* Parses text as option i's value and keeps it, set by the configuration
 * or not. */
static int store(struct asph_options *o, int i, const char *text, bool set,
		 struct asph_error *err)
{
	struct asph_option_value v = { 0 };
	_cleanup_free_ char *copy = strdup(text);

	if (!copy)
		return asph_error_set(err, -ENOMEM, "out of memory");
	int r = option_parse(&o->drv->options[i], copy, &v, err);
	if (r < 0)
		return r;
	v.set = set;
	free(o->texts[i]);
	o->texts[i] = steal_ptr(copy);
	o->values[i] = v;
	return 0;
}

int asph_options_set(struct asph_options *o, const char *name,
		     const char *text, struct asph_error *err)
{
	int i = asph_option_index(o->drv, name);

	if (i < 0) {
		char hint[96];
		return asph_error_set_at(err, -ENOENT, NULL, 0, 0, name,
					 "driver '%s' has no option '%s'%s (see asph drivers)",
					 o->drv->name, name, option_hint(o->drv, name, hint, sizeof(hint)));
	}
	return store(o, i, text, true, err);
}

int asph_options_set_default(struct asph_options *o, const char *name,
			     const char *text, struct asph_error *err)
{
	int i = asph_option_index(o->drv, name);

	if (i < 0 || o->values[i].set)
		return 0;
	int r = store(o, i, text, false, err);
	return r < 0 ? r : 1;
}

int asph_options_copy(const struct asph_options *o, struct asph_options **out,
		      struct asph_error *err)
{
	struct asph_options *c = NULL;
	int r = asph_options_new(o->drv, &c, err);

	for (size_t i = 0; r == 0 && i < o->drv->n_options; i++)
		if (o->texts[i])
			r = store(c, (int)i, o->texts[i], o->values[i].set, err);
	if (r < 0) {
		asph_options_free(c);
		return r;
	}
	*out = c;
	return 0;
}

const struct asph_option_value *asph_options_values(const struct asph_options *o)
{
	return o->values;
}

const struct asph_driver *asph_options_driver(const struct asph_options *o)
{
	return o->drv;
}

const char *asph_option_value_format(const struct asph_option_value *v,
				     char *buf, size_t size)
{
	switch (v->type) {
	case ASPH_OPTION_BOOL:
		snprintf(buf, size, "%s", v->b ? "true" : "false");
		break;
	case ASPH_OPTION_INT:
		snprintf(buf, size, "%lld", (long long)v->i);
		break;
	case ASPH_OPTION_DOUBLE:
		snprintf(buf, size, "%.17g", v->d);
		break;
	case ASPH_OPTION_STRING:
	case ASPH_OPTION_ENUM:
		snprintf(buf, size, "%s", v->s ? v->s : "");
		break;
	}
	return buf;
}
