/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Who may do what. A peer is a connected client as the kernel (unix
 * socket) or the transport (TCP) tells who it is. root and the members of
 * the operator group operate over the unix socket; over TCP a peer that
 * sent the token in "hello" operates. access_load() reads what this
 * needs from the settings (the operator group, the token file) and is the
 * same call for `asphd --check-config`, at startup and on reload, so that
 * the three agree. Event loop thread.
 */
#ifndef ASPHD_ACCESS_H
#define ASPHD_ACCESS_H

#include <stdbool.h>
#include <sys/types.h>

#include "settings.h"

/* The shortest token a token file may hold. */
#define ACCESS_TOKEN_MIN 16

struct peer {
	bool tcp;
	uid_t uid;              /* (uid_t)-1 when not known (TCP) */
	gid_t gid;
	pid_t pid;
	gid_t *groups;          /* supplementary groups; the transport owns them */
	int n_groups;
	char name[64];          /* user name, "uid N", or "tcp peer" */
};

struct access;

/*
 * Resolves s's operator group and reads its token file (owned by the
 * user that runs this, readable by it only, a token of ACCESS_TOKEN_MIN
 * characters or more). Each problem is reported through report (may be
 * NULL) with the setting and its place in the file; returns 0, -EINVAL
 * when there was any, or -ENOMEM.
 */
int access_load(const struct settings *s, struct access **out, settings_error_fn report,
		void *data);
void access_free(struct access *a);

/* Whether p may call the mutating methods; authenticated: a TCP peer has
 * sent the token. */
bool access_is_operator(const struct access *a, const struct peer *p, bool authenticated);
/* Whether token is the TCP token, in time that does not depend on where
 * they differ. False when there is no token. */
bool access_token_matches(const struct access *a, const char *token);

#endif
