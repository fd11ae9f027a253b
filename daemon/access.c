/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Event loop thread: the operator group and the TCP token. */
#include <errno.h>
#include <fcntl.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "access.h"
#include "account.h"
#include "util-mem.h"

struct access {
	bool have_operator_group;
	gid_t operator_gid;
	char *token;            /* TCP token, or NULL */
};

struct loader {
	const struct settings *s;
	settings_error_fn report;
	void *data;
	int n_errors;
};

static void complain(struct loader *ld, const char *field, int code, const char *fmt, ...)
	__attribute__((format(printf, 4, 5)));

static void complain(struct loader *ld, const char *field, int code, const char *fmt, ...)
{
	struct asph_error e;
	va_list ap;

	asph_error_clear(&e);
	e.code = code;
	va_start(ap, fmt);
	vsnprintf(e.message, sizeof(e.message), fmt, ap);
	va_end(ap);
	settings_locate(ld->s, field, &e);
	ld->n_errors++;
	if (ld->report)
		ld->report(&e, ld->data);
}

static void load_group(struct loader *ld, struct access *a)
{
	const char *name = ld->s->operator_group;
	int r;

	if (!name)
		return;
	r = account_group_id(name, &a->operator_gid);
	if (r < 0) {
		complain(ld, "operator_group", r, "group \"%s\" %s", name,
			 r == -ENOENT ? "does not exist" : strerror(-r));
		return;
	}
	a->have_operator_group = true;
}

/* The first line of the token file, without its end. */
static void load_token(struct loader *ld, struct access *a)
{
	const char *path = ld->s->token_file;
	_cleanup_fclose_ FILE *f = NULL;
	char buf[512];
	struct stat st;

	if (!path)
		return;
	f = fopen(path, "re");
	if (!f) {
		complain(ld, "token_file", -errno, "cannot read the token file %s: %s", path,
			 strerror(errno));
		return;
	}
	if (fstat(fileno(f), &st) < 0 || (st.st_mode & 0077) || st.st_uid != geteuid()) {
		complain(ld, "token_file", -EPERM, "the token file %s must belong to the daemon's "
			 "user (uid %u) and be readable by its owner only", path, (unsigned)geteuid());
		return;
	}
	if (!fgets(buf, sizeof(buf), f))
		buf[0] = '\0';
	buf[strcspn(buf, "\r\n")] = '\0';
	if (!buf[0]) {
		complain(ld, "token_file", -EINVAL, "the token file %s is empty: it must hold "
			 "the token (%d characters or more) on its first line", path, ACCESS_TOKEN_MIN);
		return;
	}
	if (strlen(buf) < ACCESS_TOKEN_MIN) {
		complain(ld, "token_file", -EINVAL, "the token in %s is shorter than %d characters",
			 path, ACCESS_TOKEN_MIN);
		return;
	}
	a->token = strdup(buf);
	if (!a->token)
		complain(ld, "token_file", -ENOMEM, "out of memory");
	explicit_bzero(buf, sizeof(buf));
}

int access_load(const struct settings *s, struct access **out, settings_error_fn report,
		void *data)
{
	struct loader ld = { .s = s, .report = report, .data = data };
	struct access *a = calloc(1, sizeof(*a));

	if (!a)
		return -ENOMEM;
	load_group(&ld, a);
	load_token(&ld, a);
	if (ld.n_errors) {
		access_free(a);
		return -EINVAL;
	}
	*out = a;
	return 0;
}

void access_free(struct access *a)
{
	if (!a)
		return;
	if (a->token) {
		explicit_bzero(a->token, strlen(a->token));
		free(a->token);
	}
	free(a);
}

bool access_is_operator(const struct access *a, const struct peer *p, bool authenticated)
{
	if (p->tcp)
		return authenticated && a->token;
	if (p->uid == 0)
		return true;
	if (!a->have_operator_group)
		return false;
	if (p->gid == a->operator_gid)
		return true;
	for (int i = 0; i < p->n_groups; i++)
		if (p->groups[i] == a->operator_gid)
			return true;
	return false;
}

bool access_token_matches(const struct access *a, const char *token)
{
	/* Constant time in the token's length. */
	size_t n = a->token ? strlen(a->token) : 0, m = token ? strlen(token) : 0;
	unsigned diff = (unsigned)(n != m) | (unsigned)!token | (unsigned)!a->token;

	for (size_t i = 0; token && i < n; i++)
		diff |= (unsigned)(a->token[i] ^ (i < m ? token[i] : 0));
	return !diff;
}
