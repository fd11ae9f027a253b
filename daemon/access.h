/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Who may do what. A peer is a connected client as the kernel (unix
 * socket) or the transport (TCP) tells who it is. root and the members of
 * the operator group operate over the unix socket, with the groups the
 * kernel gave the peer when it connected; over TCP a peer operates with
 * what it proved in "hello": a grant for a credential (today the one token
 * of token_file; the named tokens of a later version are more
 * credentials, each with its role). A grant records which credential and
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
	bool operator;                  /* the credential's role */
	char credential[64];            /* its name: "token_file" */
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

/* Whether p may call the mutating methods; g: what a TCP peer proved
 * (NULL or not valid: nothing). */
bool access_is_operator(const struct access *a, const struct peer *p,
			const struct access_grant *g);

/*
 * Checks token against the credentials, in time that does not depend on
 * where they differ: 0 with *g filled, or -EACCES (no such token, or no
 * token configured).
 */
int access_authenticate(const struct access *a, const char *token, struct access_grant *g);
/* Whether g still stands: its credential exists with the same secret. */
bool access_grant_current(const struct access *a, const struct access_grant *g);
/* Whether a TCP token is configured at all. */
bool access_has_token(const struct access *a);

/*
 * The estimated strength of a token in bits: the characters that neither
 * repeat nor continue by one step the character before them, times log2
 * of the number of different characters it uses. "aaaa...", "abab...",
 * "0123..." score near 0; 32 random hex digits about 100.
 */
double access_token_strength(const char *token);

#endif
