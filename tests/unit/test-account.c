/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The user and group lookups of asphd (daemon/account.c): the growing
 * buffer against a lookup that wants more room, and the real databases
 * for the entries every system has (root, uid and gid 0). */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "account.h"

/* A lookup that needs `need` bytes and records the sizes it was given. */
struct fake {
	size_t need;
	int result;             /* once the buffer is large enough */
	bool found;
	size_t sizes[32];
	int calls;
};

static int fake_lookup(const void *key, void *entry, char *buf, size_t size, bool *found)
{
	struct fake *f = (struct fake *)key;

	f->sizes[f->calls++] = size;
	*found = false;
	if (size < f->need)
		return ERANGE;
	/* the whole buffer is the caller's to use */
	memset(buf, 'x', size - 1);
	buf[size - 1] = '\0';
	*(char **)entry = buf;
	*found = f->found;
	return f->result;
}

static void test_grows(void **state)
{
	struct fake f = { .need = 5000, .found = true };
	char *entry = NULL, *buf = NULL;

	assert_int_equal(account_lookup(fake_lookup, &f, &entry, 1000, &buf), 0);
	/* 1000, 2000, 4000, 8000: doubled until it fits */
	assert_int_equal(f.calls, 4);
	assert_int_equal(f.sizes[0], 1000);
	assert_int_equal(f.sizes[3], 8000);
	assert_ptr_equal(entry, buf);
	assert_int_equal(strlen(buf), 7999);
	free(buf);

	/* no hint: a default first size, still grown to fit */
	f = (struct fake){ .need = 3333, .found = true };
	assert_int_equal(account_lookup(fake_lookup, &f, &entry, 0, &buf), 0);
	assert_true(f.sizes[0] > 0 && f.sizes[f.calls - 1] >= 3333);
	free(buf);
}

static void test_failures(void **state)
{
	struct fake f = { .need = 10, .found = false };
	char *entry = NULL, *buf = NULL;

	/* glibc: 0 and no entry; POSIX also allows ENOENT and ESRCH */
	assert_int_equal(account_lookup(fake_lookup, &f, &entry, 64, &buf), -ENOENT);
	f = (struct fake){ .need = 10, .result = ESRCH };
	assert_int_equal(account_lookup(fake_lookup, &f, &entry, 64, &buf), -ENOENT);
	f = (struct fake){ .need = 10, .result = EIO };
	assert_int_equal(account_lookup(fake_lookup, &f, &entry, 64, &buf), -EIO);
	/* an entry larger than the limit: -ERANGE after the largest buffer */
	f = (struct fake){ .need = ACCOUNT_BUFFER_MAX + 1, .found = true };
	assert_int_equal(account_lookup(fake_lookup, &f, &entry, 1u << 19, &buf), -ERANGE);
	assert_int_equal(f.sizes[f.calls - 1], ACCOUNT_BUFFER_MAX);
	assert_null(buf);
}

static void test_databases(void **state)
{
	char name[64];
	gid_t gid = 4242;

	assert_int_equal(account_user_name(0, name, sizeof(name)), 0);
	assert_string_equal(name, "root");
	assert_int_equal(account_group_name(0, name, sizeof(name)), 0);
	assert_string_equal(name, "root");
	assert_int_equal(account_group_id("root", &gid), 0);
	assert_int_equal(gid, 0);
	/* truncated to the room given */
	assert_int_equal(account_user_name(0, name, 3), 0);
	assert_string_equal(name, "ro");
	/* ids and names no system has */
	gid = 4242;
	assert_int_equal(account_group_id("asphd-test-no-such-group", &gid), -ENOENT);
	assert_int_equal(gid, 4242);
	assert_int_equal(account_user_name((uid_t)2147483646, name, sizeof(name)), -ENOENT);
	assert_int_equal(account_group_name((gid_t)2147483646, name, sizeof(name)), -ENOENT);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_grows),
		cmocka_unit_test(test_failures),
		cmocka_unit_test(test_databases),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
