/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The descriptors a unix peer passed (SCM_RIGHTS), held by its session
 * until a request takes one (job.submit's "measured"): at most
 * RPC_SESSION_MAX_FDS, the rest closed as they come, all closed with the
 * session. Event loop thread.
 */
#include <errno.h>
#include <string.h>
#include <unistd.h>

#include "rpc-internal.h"

bool rpc_session_add_fd(struct rpc_session *s, int fd)
{
	if (s->n_fds >= RPC_SESSION_MAX_FDS) {
		close(fd);
		return false;
	}
	s->fds[s->n_fds++] = fd;
	return true;
}

void rpc_session_close_fds(struct rpc_session *s)
{
	while (s->n_fds > 0)
		close(s->fds[--s->n_fds]);
}

int rpc_session_take_fd(struct rpc_session *s, unsigned index)
{
	int fd;

	if (index >= s->n_fds)
		return -ENOENT;
	fd = s->fds[index];
	memmove(&s->fds[index], &s->fds[index + 1], (s->n_fds - index - 1) * sizeof(int));
	s->n_fds--;
	return fd;
}
