/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Event loop thread: the operator group, the TCP tokens, the roles. */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "access.h"
#include "account.h"
#include "log.h"
#include "util-hash.h"
#include "util-mem.h"
#include "util-time.h"

/* The name of the one credential there is today. */
#define TOKEN_FILE_CREDENTIAL "token_file"

struct access {
	bool have_operator_group;
	gid_t operator_gid;
	char *token;            /* token_file's, or NULL */
	uint8_t token_digest[32];
	const struct tokens *tokens;    /* the named ones, or NULL */
};

struct loader {
	const struct settings *s;
	settings_error_fn report;
	void *data;
	int n_errors;
	bool deprecated;        /* token_file is used */
};

static void complain(struct loader *ld, const char *field, int code, const char *fmt, ...)
	__attribute__((format(printf, 4, 5)));

static void complain(struct loader *ld, const char *field, int code, const char *fmt, ...)
{
	va_list ap;

	va_start(ap, fmt);
	settings_vreport(ld->s, field, code, ld->report, ld->data, fmt, ap);
	va_end(ap);
	ld->n_errors++;
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

static void digest_of(const char *token, uint8_t digest[32])
{
	struct sha256_ctx h;

	sha256_init(&h);
	sha256_update(&h, strlen(token), (const uint8_t *)token);
	sha256_digest(&h, SHA256_DIGEST_SIZE, digest);
	explicit_bzero(&h, sizeof(h));
}

double access_token_strength(const char *token)
{
	bool seen[256] = { false };
	size_t counted = 0, distinct = 0;
	const unsigned char *t = (const unsigned char *)token;

	for (size_t i = 0; t[i]; i++) {
		if (!seen[t[i]]) {
			seen[t[i]] = true;
			distinct++;
		}
		if (i == 0 || (t[i] != t[i - 1] && t[i] != t[i - 1] + 1 && t[i] + 1 != t[i - 1]))
			counted++;
	}
	return distinct > 1 ? (double)counted * log2((double)distinct) : 0;
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
	if (access_token_strength(buf) < ACCESS_TOKEN_MIN_BITS) {
		complain(ld, "token_file", -EINVAL, "the token in %s is too easy to guess "
			 "(about %.0f bits, %d needed: repeated or consecutive characters and a "
			 "small alphabet count little); make one with `head -c 32 /dev/urandom | "
			 "base64`", path, access_token_strength(buf), ACCESS_TOKEN_MIN_BITS);
		explicit_bzero(buf, sizeof(buf));
		return;
	}
	a->token = strdup(buf);
	if (!a->token)
		complain(ld, "token_file", -ENOMEM, "out of memory");
	else
		digest_of(a->token, a->token_digest);
	explicit_bzero(buf, sizeof(buf));
	if (a->token && ld->report)
		ld->deprecated = true;
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
	if (ld.deprecated)
		log_warning("token_file is deprecated: its token is one admin token named "
			    "\"token_file\"; make named tokens with `asphctl token create NAME "
			    "--role ROLE` and remove token_file");
	*out = a;
	return 0;
}

void access_set_tokens(struct access *a, const struct tokens *t)
{
	a->tokens = t;
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

static bool in_operator_group(const struct access *a, const struct peer *p)
{
	if (!a->have_operator_group)
		return false;
	if (p->gid == a->operator_gid)
		return true;
	for (int i = 0; i < p->n_groups; i++)
		if (p->groups[i] == a->operator_gid)
			return true;
	return false;
}

enum access_role access_role_of(const struct access *a, const struct peer *p,
				const struct access_grant *g)
{
	if (p->tcp)
		return g && g->valid && access_grant_current(a, g) ? g->role : ROLE_NONE;
	if (p->uid == 0)
		return ROLE_ADMIN;
	return in_operator_group(a, p) ? ROLE_OPERATOR : ROLE_VIEWER;
}

bool access_is_operator(const struct access *a, const struct peer *p,
			const struct access_grant *g)
{
	return access_role_of(a, p, g) >= ROLE_OPERATOR;
}

int access_authenticate(const struct access *a, const char *token, struct access_grant *g)
{
	static const uint8_t none[32];
	struct token_info named;
	uint8_t digest[32];
	bool file_match;
	int r;

	*g = (struct access_grant){ 0 };
	if (!token)
		return -EACCES;
	/* Both comparisons run, each over whole digests (tokens_match()). */
	digest_of(token, digest);
	file_match = tokens_digest_equal(a->token ? a->token_digest : none, digest) && a->token;
	r = a->tokens ? tokens_match(a->tokens, digest, &named) : -ENOENT;
	if (file_match) {
		*g = (struct access_grant){ .valid = true, .role = ROLE_ADMIN, .token_file = true };
		snprintf(g->credential, sizeof(g->credential), "%s", TOKEN_FILE_CREDENTIAL);
	} else if (r == 0) {
		snprintf(g->credential, sizeof(g->credential), "%s", named.name);
		if (named.revoked_ns)
			return -EKEYREVOKED;
		if (named.expires_ns && named.expires_ns <= now_realtime_ns())
			return -EKEYEXPIRED;
		*g = (struct access_grant){ .valid = true, .role = named.role };
		snprintf(g->credential, sizeof(g->credential), "%s", named.name);
	} else {
		return -EACCES;
	}
	memcpy(g->digest, digest, sizeof(g->digest));
	return 0;
}

bool access_grant_current(const struct access *a, const struct access_grant *g)
{
	if (!g->valid)
		return false;
	if (g->token_file)
		return a->token && tokens_digest_equal(g->digest, a->token_digest);
	return a->tokens && tokens_current(a->tokens, g->credential, g->digest,
					    now_realtime_ns());
}

bool access_has_token(const struct access *a)
{
	return a->token != NULL;
}
