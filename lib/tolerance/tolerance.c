/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The tolerance object (JSON), and the ISO 14253-1 decision. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include <jansson.h>

#include "asph/tolerance.h"
#include "fileio.h"
#include "jsonpos.h"
#include "quantity.h"
#include "util-mem.h"

#define MAX_TOLERANCE_BYTES (1u << 20)
#define MIN_WAVELENGTH_NM 100.0
#define MAX_WAVELENGTH_NM 20000.0

void asph_tolerance_init(struct asph_tolerance *t)
{
	memset(t, 0, sizeof(*t));
	t->wavelength_nm = ASPH_FORM_DEFAULT_WAVELENGTH_NM;
	t->A.v = t->B.v = t->C.v = NAN;
	t->rms_t.v = t->rms_i.v = t->rms_a.v = NAN;
	t->slope_rms.v = t->slope_max.v = NAN;
	t->slope_length_mm = NAN;
	t->R_mm = NAN;
}

struct ctx {
	struct json_source src;
	struct asph_error *err;
};

/* A positive finite number at member `path`; *out untouched when absent. */
static int limit(struct ctx *c, json_t *obj, const char *key, const char *path,
		 double *out)
{
	json_t *v = json_object_get(obj, key);

	if (!v)
		return 0;
	if (!json_is_number(v))
		return json_error_set_at(c->err, -EINVAL, &c->src, path, "expected a number");
	*out = json_number_value(v);
	if (!(*out > 0) || !isfinite(*out))
		return json_error_set_at(c->err, -EINVAL, &c->src, path,
					 "%g is not a tolerance: it must be greater than 0", *out);
	return 0;
}

static int only_keys(struct ctx *c, json_t *obj, const char *const *keys,
		     const char *parent)
{
	const char *k;
	json_t *v;
	char path[160];

	json_object_foreach(obj, k, v) {
		int known = 0;
		for (size_t i = 0; keys[i]; i++)
			known |= !strcmp(k, keys[i]);
		if (!known) {
			snprintf(path, sizeof(path), "%s%s%s", parent, *parent ? "." : "", k);
			return json_error_set_at(c->err, -EINVAL, &c->src, path,
						 "unknown member (a typing error?)");
		}
	}
	return 0;
}

static int object_member(struct ctx *c, json_t *root, const char *key, json_t **out)
{
	*out = json_object_get(root, key);
	if (*out && !json_is_object(*out))
		return json_error_set_at(c->err, -EINVAL, &c->src, key, "expected an object");
	return 0;
}

/* Line, column and byte offset of the value of member key (the string's
 * opening quote); key NULL: the document itself. */
static long value_offset(const struct json_source *src, const char *key, int *line,
			 int *col)
{
	size_t pos = 0;
	int l = 1, cc = 1;

	if (key && json_locate_dotted(src->text, src->len, key, &l, &cc) < 0)
		return -1;
	for (int i = 1; i < l; i++) {
		const char *nl = memchr(src->text + pos, '\n', src->len - pos);
		if (!nl)
			return -1;
		pos = (size_t)(nl - src->text) + 1;
	}
	pos += (size_t)(cc - 1);
	if (key) {   /* skip "key" : */
		pos++;
		while (pos < src->len && src->text[pos] != '"')
			pos += src->text[pos] == '\\' ? 2 : 1;
		pos++;
	}
	while (pos < src->len && src->text[pos] != '"')
		pos++;
	if (pos >= src->len)
		return -1;
	/* The column of pos on its line. */
	size_t start = pos;
	while (start > 0 && src->text[start - 1] != '\n')
		start--;
	*col = (int)(pos - start) + 1;
	*line = 1;
	for (size_t i = 0; i < pos; i++)
		*line += src->text[i] == '\n';
	return (long)pos;
}

/* The text column of byte `decoded` (1-based) of the string whose opening
 * quote is at offset q: escapes are wider in the text than decoded. */
static int string_column(const struct json_source *src, long q, int qcol, int decoded)
{
	size_t pos = (size_t)q + 1;
	int out = 1;

	while (out < decoded && pos < src->len && src->text[pos] != '"') {
		if (src->text[pos] == '\\' && pos + 1 < src->len && src->text[pos + 1] == 'u') {
			char hex[5] = "";
			size_t avail = src->len - (pos + 2);
			memcpy(hex, src->text + pos + 2, avail < 4 ? avail : 4);
			unsigned cp = (unsigned)strtoul(hex, NULL, 16);
			out += cp < 0x80 ? 1 : cp < 0x800 ? 2 : (cp >= 0xd800 && cp < 0xdc00) ? 4 : 3;
			pos += (cp >= 0xd800 && cp < 0xdc00) ? 12 : 6;
		} else {
			out += 1;
			pos += src->text[pos] == '\\' ? 2 : 1;
		}
	}
	return qcol + (int)(pos - (size_t)q);
}

static int callout(struct ctx *c, json_t *v, const char *key, struct asph_tolerance *t)
{
	int column = 0, line = 0, col = 0, r;
	long q;

	if (!json_is_string(v))
		return json_error_set_at(c->err, -EINVAL, &c->src, key ? key : "",
					 "the call-out must be a string");
	if (strlen(json_string_value(v)) != json_string_length(v))
		return json_error_set_at(c->err, -EINVAL, &c->src, key ? key : "",
					 "the call-out holds a NUL character");
	r = asph_tolerance_parse_callout(json_string_value(v), t->wavelength_nm, t, &column,
					 c->err);
	if (r == 0)
		return 0;
	/* Point at the character in the text, message kept. */
	q = c->src.text ? value_offset(&c->src, key, &line, &col) : -1;
	if (q >= 0 && column > 0)
		col = string_column(&c->src, q, col, column);
	else
		line = col = 0;
	asph_error_locate(c->err, c->src.name, line, col, "iso10110_5");
	return r;
}

static int agree(struct ctx *c, double callout_nm, double *member, const char *path)
{
	if (isnan(callout_nm) || isnan(*member))
		return 0;
	if (fabs(callout_nm - *member) > 1e-9 * fmax(callout_nm, *member))
		return json_error_set_at(c->err, -EINVAL, &c->src, path,
					 "%g nm disagrees with the call-out's %g nm", *member,
					 callout_nm);
	return 0;
}

static int rms_members(struct ctx *c, json_t *root, struct asph_tolerance *t)
{
	static const char *const keys[] = { "t", "i", "a", NULL };
	double v[3] = { NAN, NAN, NAN };
	asph_nm *dst[3] = { &t->rms_t, &t->rms_i, &t->rms_a };
	json_t *o;
	int r = object_member(c, root, "rms_nm", &o);

	if (r < 0 || !o)
		return r;
	if ((r = only_keys(c, o, keys, "rms_nm")) < 0)
		return r;
	for (int k = 0; k < 3; k++) {
		char path[16];
		snprintf(path, sizeof(path), "rms_nm.%s", keys[k]);
		if ((r = limit(c, o, keys[k], path, &v[k])) < 0 ||
		    (r = agree(c, dst[k]->v, &v[k], path)) < 0)
			return r;
		if (!isnan(v[k]))
			dst[k]->v = v[k];
	}
	return 0;
}

static int slope_members(struct ctx *c, json_t *root, struct asph_tolerance *t)
{
	static const char *const keys[] = { "rms", "max", "length_mm", NULL };
	json_t *o;
	int r = object_member(c, root, "slope_urad", &o);

	if (r < 0 || !o)
		return r;
	if ((r = only_keys(c, o, keys, "slope_urad")) < 0 ||
	    (r = limit(c, o, "rms", "slope_urad.rms", &t->slope_rms.v)) < 0 ||
	    (r = limit(c, o, "max", "slope_urad.max", &t->slope_max.v)) < 0 ||
	    (r = limit(c, o, "length_mm", "slope_urad.length_mm", &t->slope_length_mm)) < 0)
		return r;
	if (isnan(t->slope_rms.v) && isnan(t->slope_max.v))
		return json_error_set_at(c->err, -EINVAL, &c->src, "slope_urad",
					 "needs \"rms\" or \"max\"");
	if (isnan(t->slope_length_mm))
		return json_error_set_at(c->err, -EINVAL, &c->src, "slope_urad",
					 "needs \"length_mm\": a slope means nothing without its "
					 "evaluation length");
	return 0;
}

static int wavelength(struct ctx *c, json_t *root, struct asph_tolerance *t, int *given)
{
	json_t *v = json_object_get(root, "wavelength_nm");

	*given = v != NULL;
	if (!v)
		return 0;
	if (!json_is_number(v))
		return json_error_set_at(c->err, -EINVAL, &c->src, "wavelength_nm",
					 "expected a number");
	t->wavelength_nm = json_number_value(v);
	if (!(t->wavelength_nm >= MIN_WAVELENGTH_NM && t->wavelength_nm <= MAX_WAVELENGTH_NM))
		return json_error_set_at(c->err, -EINVAL, &c->src, "wavelength_nm",
					 "%g nm is outside %g..%g nm", t->wavelength_nm,
					 MIN_WAVELENGTH_NM, MAX_WAVELENGTH_NM);
	return 0;
}

static int any_limit(const struct asph_tolerance *t)
{
	const double v[] = { t->A.v, t->B.v, t->C.v, t->rms_t.v, t->rms_i.v, t->rms_a.v,
			     t->slope_rms.v, t->slope_max.v, t->R_mm };

	for (size_t i = 0; i < sizeof(v) / sizeof(v[0]); i++)
		if (!isnan(v[i]))
			return 1;
	return 0;
}

static int parse_object(struct ctx *c, json_t *root, struct asph_tolerance *t)
{
	static const char *const keys[] = { "iso10110_5", "wavelength_nm", "rms_nm",
					    "slope_urad", "R_mm", NULL };
	json_t *co = json_object_get(root, "iso10110_5");
	int given = 0, r;
	double w;

	if ((r = only_keys(c, root, keys, "")) < 0 || (r = wavelength(c, root, t, &given)) < 0)
		return r;
	w = t->wavelength_nm;
	if (co && (r = callout(c, co, "iso10110_5", t)) < 0)
		return r;
	if (given && t->wavelength_nm != w)
		return json_error_set_at(c->err, -EINVAL, &c->src, "wavelength_nm",
					 "%g nm disagrees with the call-out's lambda = %g nm", w,
					 t->wavelength_nm);
	if ((r = rms_members(c, root, t)) < 0 || (r = slope_members(c, root, t)) < 0 ||
	    (r = limit(c, root, "R_mm", "R_mm", &t->R_mm)) < 0)
		return r;
	if (!any_limit(t))
		return json_error_set_at(c->err, -EINVAL, &c->src, "",
					 "the tolerance names no toleranced quantity");
	return 0;
}

int asph_tolerance_parse_json(const char *text, size_t len, const char *source,
			      struct asph_tolerance *t, struct asph_error *err)
{
	struct ctx c = { .src = { text, len, source ? source : "<tolerance>" }, .err = err };
	_cleanup_(json_decrefp) json_t *root = NULL;
	json_error_t je;

	asph_tolerance_init(t);
	root = json_loadb(text, len, JSON_DECODE_ANY | JSON_REJECT_DUPLICATES, &je);
	if (!root)
		return asph_error_set_at(err, -EINVAL, c.src.name, je.line, je.column, NULL,
					 "%s", je.text);
	if (json_is_string(root)) {
		int r = callout(&c, root, NULL, t);
		return r;
	}
	if (!json_is_object(root))
		return asph_error_set_at(err, -EINVAL, c.src.name, 1, 1, NULL,
					 "a tolerance is an object or a call-out string");
	return parse_object(&c, root, t);
}

/* The JSON text of a bare call-out: the JSON string holding it. */
static char *callout_json(const char *arg)
{
	_cleanup_(json_decrefp) json_t *s = json_string(arg);

	return s ? json_dumps(s, JSON_ENCODE_ANY) : NULL;
}

int asph_tolerance_load_text(const char *arg, struct asph_tolerance *t, char **text,
			     struct asph_error *err)
{
	_cleanup_free_ char *own = NULL;
	size_t len;
	int r, column = 0;

	if (!arg[strspn(arg, " \t\r\n")])
		return asph_error_set(err, -EINVAL, "empty: give an ISO 10110-5 call-out, JSON text "
				      "or a file holding it");
	switch (asph_tolerance_arg_kind(arg)) {
	case ASPH_TOLERANCE_ARG_JSON:
		own = strdup(arg);
		r = asph_tolerance_parse_json(arg, strlen(arg), "<tolerance>", t, err);
		break;
	case ASPH_TOLERANCE_ARG_CALLOUT:
		asph_tolerance_init(t);
		r = asph_tolerance_parse_callout(arg, t->wavelength_nm, t, &column, err);
		if (r < 0 && err)
			asph_error_set_at(err, r, NULL, 0, 0, NULL, "'%.160s', column %d: %s", arg,
					  column, err->message);
		if (r == 0)
			own = callout_json(arg);
		break;
	default:
		r = file_read_all(arg, MAX_TOLERANCE_BYTES, &own, &len, err);
		if (r < 0)
			return r;
		r = asph_tolerance_parse_json(own, len, strcmp(arg, "-") ? arg : "<stdin>", t, err);
		break;
	}
	if (r == 0 && !own)
		return asph_error_set(err, -ENOMEM, "out of memory");
	if (r == 0 && text)
		*text = steal_ptr(own);
	return r;
}

int asph_tolerance_load(const char *arg, struct asph_tolerance *t,
			struct asph_error *err)
{
	return asph_tolerance_load_text(arg, t, NULL, err);
}

const char *asph_verdict_name(enum asph_verdict v)
{
	switch (v) {
	case ASPH_VERDICT_PASS:
		return "pass";
	case ASPH_VERDICT_FAIL:
		return "fail";
	default:
		return "undecided";
	}
}

enum asph_verdict asph_verdict_decide(double value, double U, double limit)
{
	if (isnan(value) || isnan(U) || U < 0 || isnan(limit))
		return ASPH_VERDICT_UNDECIDED;
	if (value + U <= limit)
		return ASPH_VERDICT_PASS;
	if (value - U > limit)
		return ASPH_VERDICT_FAIL;
	return ASPH_VERDICT_UNDECIDED;
}

static void add_item(struct asph_verdict_report *r, const char *quantity, double value,
		     double U, double limit)
{
	const struct quantity *q = quantity_by_verdict(quantity);
	struct asph_verdict_item *it;

	if (isnan(limit) || r->n_items >= ASPH_VERDICT_MAX_ITEMS)
		return;
	it = &r->items[r->n_items++];
	it->quantity = quantity;
	it->value = value;
	it->U = U;
	it->limit = limit;
	/* A and R - R_nominal keep their sign; their zone is [-limit, limit] */
	it->verdict = asph_verdict_decide(q && q->two_sided ? fabs(value) : value, U, limit);
	if (it->verdict == ASPH_VERDICT_FAIL)
		r->overall = ASPH_VERDICT_FAIL;
	else if (it->verdict == ASPH_VERDICT_UNDECIDED && r->overall == ASPH_VERDICT_PASS)
		r->overall = ASPH_VERDICT_UNDECIDED;
}

void asph_verdict_evaluate(const struct asph_tolerance *t,
			   const struct asph_form *form,
			   const struct asph_slope *slope, double R_dev,
			   const struct asph_uncertainty_k2 *U,
			   struct asph_verdict_report *out)
{
	double nan = NAN;

	memset(out, 0, sizeof(*out));
	out->present = 1;
	out->overall = ASPH_VERDICT_PASS;
	add_item(out, "A_nm", form ? form->A.v : nan, U->A.v, t->A.v);
	add_item(out, "B_nm", form ? form->B.v : nan, U->B.v, t->B.v);
	add_item(out, "C_nm", form ? form->C.v : nan, U->C.v, t->C.v);
	add_item(out, "rms_t_nm", form ? form->rms_t.v : nan, U->rms_t.v, t->rms_t.v);
	add_item(out, "rms_i_nm", form ? form->rms_i.v : nan, U->rms_i.v, t->rms_i.v);
	add_item(out, "rms_a_nm", form ? form->rms_a.v : nan, U->rms_a.v, t->rms_a.v);
	add_item(out, "slope_rms_urad", slope ? slope->rms.v : nan, U->slope_rms.v,
		 t->slope_rms.v);
	add_item(out, "slope_max_urad", slope ? slope->max.v : nan, U->slope_max.v,
		 t->slope_max.v);
	add_item(out, "R_deviation_mm", R_dev, U->R_mm, t->R_mm);
}
