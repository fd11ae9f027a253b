/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Named API tokens (asphctl token create|list|revoke): each a name, a role
 * (viewer, operator, admin), an optional expiry, and the SHA-256 of its
 * secret. The secret is made here from the kernel's random numbers, shown
 * once to whoever created it and never kept. The tokens live in the job
 * store (their own connection to it) and in memory, where a hello is
 * checked against every one of them in the same time whichever matches,
 * if any (tokens_match()). They outlive reloads; access.c consults them.
 * Event loop thread.
 */
#ifndef ASPHD_TOKENS_H
#define ASPHD_TOKENS_H

#include <stdbool.h>
#include <stdint.h>

#include <jansson.h>

#include "asph/error.h"

/* What a credential allows (docs/daemon.md, "Roles"): each includes the
 * one before. */
enum access_role {
	ROLE_NONE = 0,          /* nothing but hello */
	ROLE_VIEWER,            /* the reading methods */
	ROLE_OPERATOR,          /* and the mutating ones */
	ROLE_ADMIN,             /* and the tokens, a lock held by another */
};

const char *access_role_name(enum access_role r);
/* 0, or -EINVAL for a name that is none of viewer, operator, admin. */
int access_role_from_name(const char *name, enum access_role *out);

/* A token's secret: "asph_" and 43 characters of base64url (256 bits). */
#define TOKENS_SECRET_SIZE 49
/* The longest name; names are letters, digits and "._@-". */
#define TOKENS_NAME_MAX 64

struct token_info {
	char name[TOKENS_NAME_MAX + 1];
	enum access_role role;
	int64_t expires_ns;     /* 0: never */
	int64_t revoked_ns;     /* 0: not revoked */
};

struct tokens;

/* Opens the tokens of the store at path. */
int tokens_open(const char *path, struct tokens **out, struct asph_error *err);
void tokens_free(struct tokens *t);

/*
 * A new token: its secret in secret (to be shown once, then forgotten).
 * -EINVAL for a bad name or an expiry in the past, -EEXIST for a name
 * taken (also by a revoked token: names are not reused, so that the
 * history stays unambiguous).
 */
int tokens_create(struct tokens *t, const char *name, enum access_role role,
		  int64_t expires_ns, const char *creator, char secret[TOKENS_SECRET_SIZE],
		  struct asph_error *err);
/* -ENOENT no such token, -EALREADY revoked before. */
int tokens_revoke(struct tokens *t, const char *name, struct asph_error *err);
/* token.list's result: every token without its secret. */
json_t *tokens_to_json(const struct tokens *t);

/*
 * The token whose secret has this SHA-256: every token's digest is
 * compared in full whether or not one matched before, so the time does
 * not depend on which token matches or where a digest differs. 0 with
 * *out filled (also for a revoked or expired token: the caller says so),
 * or -ENOENT.
 */
int tokens_match(const struct tokens *t, const uint8_t digest[32], struct token_info *out);
/* Whether the token name with this digest exists, is not revoked and has
 * not expired at now_ns. */
bool tokens_current(const struct tokens *t, const char *name, const uint8_t digest[32],
		    int64_t now_ns);
/* The next expiry after now_ns of a token in use, or 0 when none. */
int64_t tokens_next_expiry(const struct tokens *t, int64_t now_ns);
/* Told after a token is created or revoked (connections with a revoked
 * token must go; a new expiry must be watched). */
void tokens_set_changed(struct tokens *t, void (*fn)(void *data), void *data);

/* Constant-time equality of two 32-byte digests. */
bool tokens_digest_equal(const uint8_t a[32], const uint8_t b[32]);

#endif
