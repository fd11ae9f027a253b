/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Who may do what (daemon/access.c): the strength rule that refuses
 * guessable tokens, the token file's checks, the grant a hello earns and
 * how a rotated or removed token takes it back, the roles of unix peers,
 * and the named tokens (daemon/tokens.c): made, matched, expired, revoked.
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
#include "rmtree.h"
#include "tokens.h"
#include "util-time.h"

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
	assert_true(g.valid && g.role == ROLE_ADMIN && g.token_file);
	assert_int_equal(access_role_of(a, &tcp, &g), ROLE_ADMIN);
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
	assert_int_equal(access_role_of(a, &root, NULL), ROLE_ADMIN);
	assert_int_equal(access_role_of(a, &reader, NULL), ROLE_VIEWER);
	assert_false(access_is_operator(a, &reader, NULL));
	assert_false(access_is_operator(a, &member, NULL));
	assert_false(access_has_token(a));
	access_free(a);
	s->operator_group = strdup("root");     /* gid 0 */
	assert_int_equal(access_load(s, &a, NULL, NULL), 0);
	assert_true(access_is_operator(a, &member, NULL));
	assert_int_equal(access_role_of(a, &member, NULL), ROLE_OPERATOR);
	assert_false(access_is_operator(a, &reader, NULL));
	access_free(a);
	settings_free(s);
}

static void test_named_tokens(void **state)
{
	char dir[] = "/tmp/test-tokens-XXXXXX", path[64], secret[TOKENS_SECRET_SIZE],
	     other[TOKENS_SECRET_SIZE];
	struct peer tcp = { .tcp = true, .uid = (uid_t)-1, .name = "tcp 192.0.2.7" };
	struct access_grant g, v;
	struct asph_error err;
	struct settings *s;
	struct tokens *t;
	struct access *a = NULL;

	assert_non_null(mkdtemp(dir));
	snprintf(path, sizeof(path), "%s/jobs.sqlite", dir);
	assert_int_equal(tokens_open(path, &t, &err), 0);
	assert_int_equal(settings_defaults(&s), 0);
	assert_int_equal(access_load(s, &a, NULL, NULL), 0);
	access_set_tokens(a, t);
	assert_int_equal(tokens_create(t, "line-3", ROLE_OPERATOR, 0, "root", secret, &err), 0);
	assert_int_equal((int)strlen(secret), TOKENS_SECRET_SIZE - 1);
	assert_true(access_token_strength(secret) >= ACCESS_TOKEN_MIN_BITS);
	assert_int_equal(tokens_create(t, "line-3", ROLE_VIEWER, 0, "root", other, &err), -EEXIST);
	assert_int_equal(tokens_create(t, "bad name", ROLE_VIEWER, 0, "root", other, &err), -EINVAL);
	assert_int_equal(tokens_create(t, "token_file", ROLE_VIEWER, 0, "root", other, &err),
			 -EINVAL);
	assert_int_equal(tokens_create(t, "wall", ROLE_VIEWER, 0, "root", other, &err), 0);
	assert_string_not_equal(secret, other);

	assert_int_equal(access_authenticate(a, secret, &g), 0);
	assert_string_equal(g.credential, "line-3");
	assert_int_equal(access_role_of(a, &tcp, &g), ROLE_OPERATOR);
	assert_int_equal(access_authenticate(a, other, &v), 0);
	assert_int_equal(access_role_of(a, &tcp, &v), ROLE_VIEWER);
	assert_false(access_is_operator(a, &tcp, &v));
	/* One character off: no token. */
	secret[10] ^= 1;
	assert_int_equal(access_authenticate(a, secret, &v), -EACCES);
	secret[10] ^= 1;

	/* Revoked: the grant no longer stands and a new hello is refused. */
	assert_int_equal(tokens_revoke(t, "line-3", &err), 0);
	assert_int_equal(tokens_revoke(t, "line-3", &err), -EALREADY);
	assert_int_equal(tokens_revoke(t, "nobody", &err), -ENOENT);
	assert_false(access_grant_current(a, &g));
	assert_int_equal(access_role_of(a, &tcp, &g), ROLE_NONE);
	assert_int_equal(access_authenticate(a, secret, &v), -EKEYREVOKED);

	/* Expired: the same, once its time has passed. */
	assert_int_equal(tokens_create(t, "soon", ROLE_ADMIN, now_realtime_ns() + 150 * NS_PER_MS,
				       "root", secret, &err), 0);
	assert_true(tokens_next_expiry(t, now_realtime_ns()) > 0);
	assert_int_equal(access_authenticate(a, secret, &g), 0);
	assert_int_equal(access_role_of(a, &tcp, &g), ROLE_ADMIN);
	msleep(200);
	assert_int_equal(access_role_of(a, &tcp, &g), ROLE_NONE);
	assert_int_equal(access_authenticate(a, secret, &v), -EKEYEXPIRED);
	assert_int_equal(tokens_create(t, "past", ROLE_ADMIN, now_realtime_ns() - NS_PER_SEC, "root",
				       secret, &err), -EINVAL);

	/* The tokens are in the store: a new process finds them, hashed. */
	tokens_free(t);
	assert_int_equal(tokens_open(path, &t, &err), 0);
	access_set_tokens(a, t);
	assert_int_equal(access_authenticate(a, other, &v), 0);
	assert_string_equal(v.credential, "wall");
	{
		json_t *list = tokens_to_json(t);
		char *text = json_dumps(list, 0);
		assert_null(strstr(text, other));
		assert_non_null(strstr(text, "\"revoked\""));
		assert_non_null(strstr(text, "\"expired\""));
		free(text);
		json_decref(list);
	}
	tokens_free(t);
	access_free(a);
	settings_free(s);
	assert_int_equal(rmtree(dir), 0);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_strength),
		cmocka_unit_test(test_token_grants),
		cmocka_unit_test(test_unix_operators),
		cmocka_unit_test(test_named_tokens),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
