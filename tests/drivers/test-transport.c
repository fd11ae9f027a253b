/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The drivers' fd transport: messages, streams, timeouts, cancel from
 * another thread, a peer that goes away. */
#include <errno.h>
#include <pthread.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <cmocka.h>

#include "transport.h"

static void pair(int type, struct transport **t, int *peer)
{
	int sv[2];
	assert_int_equal(socketpair(AF_UNIX, type | SOCK_CLOEXEC, 0, sv), 0);
	assert_int_equal(transport_new(sv[0], true, "bus0", t, NULL), 0);
	*peer = sv[1];
}

static void test_messages(void **state)
{
	struct transport *t;
	int peer;
	char buf[64];
	size_t got;
	const unsigned char frame[13] = { 0x81, 0x05, 0, 0, 8, 0x2b, 0x40, 0x60, 0, 0x0f, 0, 0, 0 };

	pair(SOCK_SEQPACKET, &t, &peer);
	assert_int_equal(transport_send(t, frame, sizeof(frame), 100, NULL), 0);
	assert_int_equal(read(peer, buf, sizeof(buf)), (ssize_t)sizeof(frame));
	assert_memory_equal(buf, frame, sizeof(frame));
	assert_int_equal(write(peer, "abc", 3), 3);
	assert_int_equal(write(peer, "defgh", 5), 5);
	/* one message per call */
	assert_int_equal(transport_recv(t, buf, sizeof(buf), &got, 100, NULL), 0);
	assert_int_equal(got, 3);
	assert_int_equal(transport_recv(t, buf, sizeof(buf), &got, 100, NULL), 0);
	assert_int_equal(got, 5);
	assert_memory_equal(buf, "defgh", 5);
	close(peer);
	transport_free(t);
}

static void test_stream_exact(void **state)
{
	struct transport *t;
	int peer;
	char buf[16];

	pair(SOCK_STREAM, &t, &peer);
	assert_int_equal(write(peer, "0123", 4), 4);
	assert_int_equal(write(peer, "456789", 6), 6);
	assert_int_equal(transport_recv_exact(t, buf, 10, 100, NULL), 0);
	assert_memory_equal(buf, "0123456789", 10);
	close(peer);
	transport_free(t);
}

static void test_timeout(void **state)
{
	struct transport *t;
	struct asph_error err;
	int peer;
	char buf[8];
	size_t got;
	struct timespec a, b;

	pair(SOCK_SEQPACKET, &t, &peer);
	clock_gettime(CLOCK_MONOTONIC, &a);
	assert_int_equal(transport_recv(t, buf, sizeof(buf), &got, 40, &err), -ETIMEDOUT);
	clock_gettime(CLOCK_MONOTONIC, &b);
	/* it waited the timeout, not less */
	assert_true((b.tv_sec - a.tv_sec) * 1000.0 + (b.tv_nsec - a.tv_nsec) / 1e6 >= 39.0);
	assert_non_null(strstr(err.message, "bus0"));
	/* a partial stream read times out too */
	close(peer);
	transport_free(t);
	pair(SOCK_STREAM, &t, &peer);
	assert_int_equal(write(peer, "01", 2), 2);
	assert_int_equal(transport_recv_exact(t, buf, 4, 30, &err), -ETIMEDOUT);
	close(peer);
	transport_free(t);
}

static void *cancel_later(void *data)
{
	struct timespec ts = { 0, 50000000 };
	nanosleep(&ts, NULL);
	transport_cancel(data);
	return NULL;
}

static void test_cancel(void **state)
{
	struct transport *t;
	struct asph_error err;
	pthread_t th;
	int peer;
	char buf[8];
	size_t got;

	pair(SOCK_SEQPACKET, &t, &peer);
	assert_int_equal(pthread_create(&th, NULL, cancel_later, t), 0);
	/* a long wait ends when another thread cancels */
	assert_int_equal(transport_recv(t, buf, sizeof(buf), &got, 600000, &err), -ECANCELED);
	pthread_join(th, NULL);
	assert_int_equal(transport_send(t, "x", 1, 100, &err), -ECANCELED);
	close(peer);
	transport_free(t);
}

static void test_peer_gone(void **state)
{
	struct transport *t;
	struct asph_error err;
	int peer;
	char buf[8];
	size_t got;

	pair(SOCK_SEQPACKET, &t, &peer);
	close(peer);
	assert_int_equal(transport_recv(t, buf, sizeof(buf), &got, 100, &err), -ENODEV);
	assert_int_equal(transport_send(t, "x", 1, 100, &err), -ENODEV);
	transport_free(t);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_messages),
		cmocka_unit_test(test_stream_exact),
		cmocka_unit_test(test_timeout),
		cmocka_unit_test(test_cancel),
		cmocka_unit_test(test_peer_gone),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
