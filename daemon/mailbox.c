/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include "log.h"
#include "mailbox.h"
#include "util-mem.h"

struct mailbox {
	struct mailbox_setup setup;
	int efd;
	sd_event_source *src;

	pthread_mutex_t lock;           /* what follows */
	unsigned char *msgs;
	size_t n, cap;
};

static unsigned char *at(unsigned char *msgs, size_t size, size_t i)
{
	return msgs + i * size;
}

static int on_wake(sd_event_source *s, int fd, uint32_t revents, void *data)
{
	struct mailbox *b = data;
	unsigned char *msgs;
	uint64_t count;
	size_t n;

	if (read(b->efd, &count, sizeof(count)) < 0 && errno != EAGAIN)
		log_warning("mailbox: cannot read its eventfd: %s", strerror(errno));
	pthread_mutex_lock(&b->lock);
	msgs = steal_ptr(b->msgs);
	n = b->n;
	b->n = b->cap = 0;
	pthread_mutex_unlock(&b->lock);
	for (size_t i = 0; i < n; i++)
		b->setup.deliver(at(msgs, b->setup.size, i), b->setup.data);
	free(msgs);
	return 0;
}

int mailbox_new(const struct mailbox_setup *setup, struct mailbox **out)
{
	struct mailbox *b = calloc(1, sizeof(*b));
	int r;

	if (!b)
		return -ENOMEM;
	b->setup = *setup;
	pthread_mutex_init(&b->lock, NULL);
	b->efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
	if (b->efd < 0) {
		r = -errno;
		mailbox_free(b);
		return r;
	}
	r = sd_event_add_io(setup->event, &b->src, b->efd, EPOLLIN, on_wake, b);
	if (r < 0) {
		mailbox_free(b);
		return r;
	}
	*out = b;
	return 0;
}

void mailbox_close(struct mailbox *b)
{
	if (b)
		b->src = sd_event_source_disable_unref(b->src);
}

void mailbox_free(struct mailbox *b)
{
	if (!b)
		return;
	mailbox_close(b);
	if (b->efd >= 0)
		close(b->efd);
	for (size_t i = 0; b->setup.drop && i < b->n; i++)
		b->setup.drop(at(b->msgs, b->setup.size, i), b->setup.data);
	free(b->msgs);
	pthread_mutex_destroy(&b->lock);
	free(b);
}

/* Under the lock: room for one more message. */
static int grow(struct mailbox *b)
{
	size_t cap = b->cap ? 2 * b->cap : 16;
	unsigned char *m;

	if (b->n < b->cap)
		return 0;
	m = realloc(b->msgs, cap * b->setup.size);
	if (!m)
		return -ENOMEM;
	b->msgs = m;
	b->cap = cap;
	return 0;
}

int mailbox_post(struct mailbox *b, void *msg)
{
	uint64_t one = 1;
	size_t size = b->setup.size;
	int r = 0;

	pthread_mutex_lock(&b->lock);
	if (b->n && b->setup.replaces && b->setup.replaces(at(b->msgs, size, b->n - 1), msg)) {
		if (b->setup.drop)
			b->setup.drop(at(b->msgs, size, b->n - 1), b->setup.data);
		memcpy(at(b->msgs, size, b->n - 1), msg, size);
	} else if ((r = grow(b)) == 0) {
		memcpy(at(b->msgs, size, b->n++), msg, size);
	}
	pthread_mutex_unlock(&b->lock);
	if (r < 0) {
		if (b->setup.drop)
			b->setup.drop(msg, b->setup.data);
		return r;
	}
	/* EAGAIN: the counter is full, and the loop is woken already. */
	if (write(b->efd, &one, sizeof(one)) < 0 && errno != EAGAIN)
		log_warning("mailbox: cannot write its eventfd: %s", strerror(errno));
	return 0;
}
