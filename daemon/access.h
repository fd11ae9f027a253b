/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Who may do what. A peer is a connected client as the kernel (unix
 * socket) or the transport (TCP) tells who it is. root and the members of
 * the operator group operate over the unix socket, with the groups the
 * kernel gave the peer when it connected; over TCP a peer operates with
 * what it proved in "hello": a grant for a credential (a named token of
 * tokens.h with its role, or the deprecated token of token_file, an
 * admin). A grant records which credential and
 * which secret it was, so that a rotated or removed token ends the
 * sessions that presented the old one. access_load() reads what this
 * needs from the settings (the operator group, the token file) and is the
 * same call for `asphd --check-config`, at startup and on reload, so that
 * the three agree. Event loop thread.
 */
#ifndef ASPHD_ACCESS_H
#define ASPHD_ACCESS_H

#include <stdbool.h>
#include <stdint.h>
#include <sys/types.h>

#include "ratelimit.h"
#include "settings.h"
#include "tokens.h"

/* The shortest token a token file may hold, and the least strength
 * (access_token_strength()) it must have. */
#define ACCESS_TOKEN_MIN 16
#define ACCESS_TOKEN_MIN_BITS 64

struct peer {
	bool tcp;
	uid_t uid;              /* (uid_t)-1 when not known (TCP) */
	gid_t gid;
	pid_t pid;
	gid_t *groups;          /* supplementary groups; the transport owns them */
	int n_groups;
	char name[64];          /* user name, "uid N", or "tcp ADDRESS" */
	/* Whose quotas and rate limits it counts against: "uid N", or for TCP
	 * "tcp ADDRESS" (an IPv6 address by its /64, what one host is given). */
	char key[RATELIMIT_KEY_MAX];
};

/* What a TCP peer proved with hello. */
struct access_grant {
	bool valid;
	enum access_role role;          /* the credential's */
	bool token_file;                /* the deprecated token of token_file */
	char credential[TOKENS_NAME_MAX + 1];   /* its name: a token's, "token_file" */
	uint8_t digest[32];             /* SHA-256 of the secret presented */
};

struct access;

/*
 * Resolves s's operator group and reads its token file (owned by the
 * user that runs this, readable by it only, a token of ACCESS_TOKEN_MIN
 * characters or more and ACCESS_TOKEN_MIN_BITS of strength). Each problem
 * is reported through report (may be NULL) with the setting and its place
 * in the file; returns 0, -EINVAL when there was any, or -ENOMEM.
 */
int access_load(const struct settings *s, struct access **out, settings_error_fn report,
		void *data);
void access_free(struct access *a);

/* The named tokens (they outlive a reload of the configuration: the
 * same tokens are given to each new struct access). May be NULL. */
void access_set_tokens(struct access *a, const struct tokens *t);

/*
 * What p may do: over the unix socket root is an admin, a member of the
 * operator group an operator, everyone else a viewer; over TCP the role of
 * the token it proved in hello (g; NULL or not valid: none), while that
 * token stands.
 */
enum access_role access_role_of(const struct access *a, const struct peer *p,
				const struct access_grant *g);
/* Whether p may call the mutating methods (an operator or an admin). */
bool access_is_operator(const struct access *a, const struct peer *p,
			const struct access_grant *g);

/*
 * Checks token against every credential (the token file's and the named
 * tokens): its SHA-256 is compared in full with each of theirs, whether
 * or not one matched, so the time does not depend on which matches or
 * where they differ. 0 with *g filled, -EACCES (no such token), -EKEYEXPIRED
 * or -EKEYREVOKED (g names the token).
 */
int access_authenticate(const struct access *a, const char *token, struct access_grant *g);
/* Whether g still stands: its credential exists with the same secret,
 * not revoked and not expired. */
bool access_grant_current(const struct access *a, const struct access_grant *g);
/* Whether the deprecated token_file is configured. */
bool access_has_token(const struct access *a);

/*
 * The estimated strength of a token in bits: the characters that neither
 * repeat nor continue by one step the character before them, times log2
 * of the number of different characters it uses. "aaaa...", "abab...",
 * "0123..." score near 0; 32 random hex digits about 100.
 */
double access_token_strength(const char *token);

#endif
