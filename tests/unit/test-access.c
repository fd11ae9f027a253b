/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Who may do what (daemon/access.c): the strength rule that refuses
 * guessable tokens, the token file's checks, the grant a hello earns and
 * how a rotated or removed token takes it back, and the operator rule for
 * unix peers.
 */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmocka.h>

#include "access.h"

static const char strong[] = "Kq8vT2mXw9LpZr4bNc7YhGd3";
static const char rotated[] = "w7RmQ2zXc9VbLk4NpT8sYhJ6";

static void test_strength(void **state)
{
	static const char *const weak[] = {
		"aaaaaaaaaaaaaaaaaaaaaaaa", "abababababababababababab", "0123456789abcdefghijklmn",
		"passwordpassword", "s3cr3t-t0ken-0123456789",
		"0123456789abcdef0123456789abcdef",
	};
	static const char *const good[] = {
		strong, rotated,
		"3f9c1a7e52b04d8896e1c0a7f35b2d4e",             /* 32 random hex digits */
		"tC9+pQ2/Lx7KmZ0aVr5WnE3yHb8SdG1uJf6Oq4Ic=",    /* 30 bytes of base64 */
		"correct-horse-battery-staple-zebra",
	};

	for (size_t i = 0; i < sizeof(weak) / sizeof(weak[0]); i++)
		if (access_token_strength(weak[i]) >= ACCESS_TOKEN_MIN_BITS)
			fail_msg("\"%s\" scores %.1f bits", weak[i], access_token_strength(weak[i]));
	for (size_t i = 0; i < sizeof(good) / sizeof(good[0]); i++)
		if (access_token_strength(good[i]) < ACCESS_TOKEN_MIN_BITS)
			fail_msg("\"%s\" scores %.1f bits", good[i], access_token_strength(good[i]));
	assert_true(access_token_strength("") == 0);
	assert_true(access_token_strength("z") == 0);
}

struct errors {
	int n;
	char last[512];
};

static void collect(const struct asph_error *err, void *data)
{
	struct errors *e = data;

	e->n++;
	snprintf(e->last, sizeof(e->last), "%s", err->message);
}

static struct access *load(const char *token_file, const char *text, struct errors *e)
{
	struct settings *s;
	struct access *a = NULL;
	FILE *f = fopen(token_file, "w");

	assert_non_null(f);
	fputs(text, f);
	fclose(f);
	assert_int_equal(chmod(token_file, 0600), 0);
	assert_int_equal(settings_defaults(&s), 0);
	s->token_file = strdup(token_file);
	*e = (struct errors){ 0 };
	access_load(s, &a, collect, e);
	settings_free(s);
	return a;
}

static void test_token_grants(void **state)
{
	char path[] = "/tmp/test-access-XXXXXX";
	struct peer tcp = { .tcp = true, .uid = (uid_t)-1, .name = "tcp 192.0.2.7" };
	struct access_grant g, none;
	struct access *a, *b;
	struct errors e;
	int fd = mkstemp(path);

	assert_true(fd >= 0);
	close(fd);
	/* A weak token is refused with the rule and a way to make one. */
	assert_null(load(path, "aaaaaaaaaaaaaaaaaaaaaaaa\n", &e));
	assert_int_equal(e.n, 1);
	assert_non_null(strstr(e.last, "too easy to guess"));
	assert_non_null(strstr(e.last, "/dev/urandom"));

	a = load(path, strong, &e);
	assert_non_null(a);
	assert_true(access_has_token(a));
	assert_int_equal(access_authenticate(a, "Kq8vT2mXw9LpZr4bNc7YhGd", &none), -EACCES);
	assert_false(none.valid);
	assert_false(access_is_operator(a, &tcp, &none));
	assert_false(access_is_operator(a, &tcp, NULL));
	assert_int_equal(access_authenticate(a, strong, &g), 0);
	assert_true(g.valid && g.operator);
	assert_string_equal(g.credential, "token_file");
	assert_true(access_is_operator(a, &tcp, &g));
	assert_true(access_grant_current(a, &g));

	/* The token rotated: the old grant no longer stands. */
	b = load(path, rotated, &e);
	assert_non_null(b);
	assert_false(access_grant_current(b, &g));
	assert_false(access_is_operator(b, &tcp, &g));
	assert_int_equal(access_authenticate(b, strong, &none), -EACCES);
	access_free(b);
	/* The same token read again: the grant stands. */
	b = load(path, strong, &e);
	assert_true(access_grant_current(b, &g));
	access_free(b);
	access_free(a);
	unlink(path);
}

static void test_unix_operators(void **state)
{
	struct settings *s;
	struct access *a = NULL;
	gid_t groups[3] = { 5, 0, 7 };
	struct peer root = { .uid = 0, .gid = 0 };
	struct peer reader = { .uid = 1000, .gid = 1000 };
	struct peer member = { .uid = 1001, .gid = 1001, .groups = groups, .n_groups = 3 };

	assert_int_equal(settings_defaults(&s), 0);
	assert_int_equal(access_load(s, &a, NULL, NULL), 0);
	assert_true(access_is_operator(a, &root, NULL));
	assert_false(access_is_operator(a, &reader, NULL));
	assert_false(access_is_operator(a, &member, NULL));
	assert_false(access_has_token(a));
	access_free(a);
	s->operator_group = strdup("root");     /* gid 0 */
	assert_int_equal(access_load(s, &a, NULL, NULL), 0);
	assert_true(access_is_operator(a, &member, NULL));
	assert_false(access_is_operator(a, &reader, NULL));
	access_free(a);
	settings_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_strength),
		cmocka_unit_test(test_token_grants),
		cmocka_unit_test(test_unix_operators),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
