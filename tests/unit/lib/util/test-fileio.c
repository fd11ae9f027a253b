/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "fileio.h"

static char path[] = "/tmp/asph-test-fileio-XXXXXX";

static void write_bytes(size_t n)
{
	FILE *f = fopen(path, "w");
	assert_non_null(f);
	for (size_t i = 0; i < n; i++)
		fputc('a' + (int)(i % 26), f);
	fclose(f);
}

static void test_limits(void **state)
{
	int fd = mkstemp(path);
	assert_true(fd >= 0);
	close(fd);
	/* sizes around the growth steps and the limit */
	const size_t sizes[] = { 0, 1, 16383, 16384, 16385, 40000 };
	for (size_t i = 0; i < sizeof(sizes) / sizeof(sizes[0]); i++) {
		char *buf = NULL;
		size_t len = 0;
		write_bytes(sizes[i]);
		assert_int_equal(file_read_all(path, 40000, &buf, &len, NULL), 0);
		assert_int_equal(len, sizes[i]);
		assert_int_equal(buf[len], '\0');
		if (len)
			assert_int_equal(buf[len - 1], 'a' + (int)((len - 1) % 26));
		free(buf);
	}
	struct asph_error err;
	char *buf = NULL;
	size_t len = 0;
	write_bytes(40001);
	assert_int_equal(file_read_all(path, 40000, &buf, &len, &err), -EFBIG);
	assert_null(buf);
	assert_string_equal(err.source, path);
	assert_non_null(strstr(err.message, "40000"));
	unlink(path);
	assert_int_equal(file_read_all(path, 10, &buf, &len, &err), -ENOENT);
	assert_non_null(strstr(err.message, "cannot open"));
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_limits),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
