/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "settings.h"

struct seen {
	int n;
	struct asph_error e[8];
};

static void collect(const struct asph_error *err, void *data)
{
	struct seen *s = data;

	if (s->n < 8)
		s->e[s->n] = *err;
	s->n++;
}

static char *write_tmp(const char *text)
{
	static char path[64];
	FILE *f;
	int fd;

	snprintf(path, sizeof(path), "/tmp/test-settings-XXXXXX");
	fd = mkstemp(path);
	assert_true(fd >= 0);
	f = fdopen(fd, "w");
	fputs(text, f);
	fclose(f);
	return path;
}

static void test_defaults(void **state)
{
	struct settings *c = NULL;

	assert_int_equal(settings_load(NULL, &c, NULL, NULL), 0);
	assert_string_equal(c->socket_path, "/run/asphd/asphd.sock");
	assert_string_equal(c->state_dir, "/var/lib/asphd");
	assert_int_equal(c->socket_mode, 0660);
	assert_null(c->operator_group);
	assert_null(c->tcp_listen);
	assert_null(c->instruments_json);
	assert_int_equal(c->limits.max_request_bytes, 1u << 20);
	settings_free(c);
}

static void test_full(void **state)
{
	struct settings *c = NULL;
	char *path = write_tmp("{\n \"operator_group\": \"lab\",\n \"socket\": \"/run/x/a.sock\",\n"
			       " \"socket_mode\": \"0640\",\n \"limits\": {\"max_queue\": 37, "
			       "\"request_timeout_ms\": 1500},\n"
			       " \"instruments\": [{\"name\": \"m\", \"stage\": {\"driver\": \"mock\"},"
			       " \"probe\": {\"driver\": \"mock\"}}]\n}\n");
	struct seen s = { 0 };

	assert_int_equal(settings_load(path, &c, collect, &s), 0);
	assert_int_equal(s.n, 0);
	assert_string_equal(c->operator_group, "lab");
	assert_string_equal(c->socket_path, "/run/x/a.sock");
	assert_int_equal(c->socket_mode, 0640);
	assert_int_equal(c->limits.max_queue, 37);
	assert_int_equal(c->limits.request_timeout_ms, 1500);
	assert_int_equal(c->limits.max_clients, 256);   /* untouched default */
	assert_non_null(strstr(c->instruments_json, "\"instruments\""));
	settings_free(c);
	unlink(path);
}

/* Every error is reported, each with its line, column and setting. */
static void test_errors(void **state)
{
	struct settings *c = NULL;
	char *path = write_tmp("{\n \"socket\": \"relative.sock\",\n \"colour\": 3,\n"
			       " \"socket_mode\": \"0666\",\n \"limits\": {\"max_queue\": 0, \"speed\": 1}\n}\n");
	struct seen s = { 0 };

	assert_int_equal(settings_load(path, &c, collect, &s), -EINVAL);
	assert_null(c);
	assert_int_equal(s.n, 5);
	assert_string_equal(s.e[0].field, "socket");
	assert_int_equal(s.e[0].line, 2);
	assert_non_null(strstr(s.e[0].message, "absolute"));
	assert_string_equal(s.e[1].field, "colour");
	assert_int_equal(s.e[1].line, 3);
	assert_string_equal(s.e[2].field, "socket_mode");
	assert_non_null(strstr(s.e[2].message, "others"));
	assert_string_equal(s.e[3].field, "limits.max_queue");
	assert_int_equal(s.e[3].line, 5);
	assert_string_equal(s.e[4].field, "limits.speed");
	unlink(path);
}

static void test_syntax_and_missing(void **state)
{
	struct settings *c = NULL;
	char *path = write_tmp("{\n \"socket\": \"/a\",\n \"limits\": {\n");
	struct seen s = { 0 };

	assert_int_equal(settings_load(path, &c, collect, &s), -EINVAL);
	assert_int_equal(s.n, 1);
	assert_int_equal(s.e[0].line, 4);
	unlink(path);
	s.n = 0;
	assert_int_equal(settings_load("/nonexistent/asphd.conf", &c, collect, &s), -ENOENT);
	assert_int_equal(s.n, 1);
	assert_string_equal(s.e[0].source, "/nonexistent/asphd.conf");
}

/* "//" comments are blanked outside strings, and only there; every place
 * after them keeps its line and column. */
static void test_comments(void **state)
{
	char text[] = "// head\n{\"a\": \"x//y\", // tail \"q\"\n \"b\": \"\\\"//\"}//end";
	const char *want = "       \n{\"a\": \"x//y\",            \n \"b\": \"\\\"//\"}     ";
	struct settings *c = NULL;
	struct seen s = { 0 };
	char *path;

	settings_blank_comments(text, strlen(text));
	assert_string_equal(text, want);
	path = write_tmp("// asphd.conf\n{\n  // the socket\n  \"socket\": \"/run/x/a.sock\", // ours\n"
			 "  \"mqtt\": {\"url\": \"mqtt://broker.lab:1883\"},\n"
			 "  \"operator_group\": 7 // wrong\n}\n");
	assert_int_equal(settings_load(path, &c, collect, &s), -EINVAL);
	assert_int_equal(s.n, 1);
	assert_string_equal(s.e[0].field, "operator_group");
	assert_int_equal(s.e[0].line, 6);
	assert_int_equal(s.e[0].column, 3);
	unlink(path);
	path = write_tmp("// asphd.conf\n{\n  // the socket\n  \"socket\": \"/run/x/a.sock\", // ours\n"
			 "  \"mqtt\": {\"url\": \"mqtt://broker.lab:1883\"}\n}\n");
	s.n = 0;
	assert_int_equal(settings_load(path, &c, collect, &s), 0);
	assert_string_equal(c->socket_path, "/run/x/a.sock");
	assert_string_equal(c->mqtt->host, "broker.lab");
	settings_free(c);
	unlink(path);
}

/* The reference of the settings is the table the file is read through:
 * each limit's default is the one loaded without a file, and each name
 * is taken in its place (an unknown one would be refused). */
static void test_reference(void **state)
{
	struct settings *c = NULL;
	struct setting_info info;
	bool have_limit = false;

	assert_int_equal(settings_load(NULL, &c, NULL, NULL), 0);
	assert_true(settings_count() > 30);
	for (size_t i = 0; i < settings_count(); i++) {
		settings_describe(i, &info);
		assert_true(info.help[0] && info.type[0] && info.fallback[0]);
		if (!strcmp(info.name, "limits.max_queue")) {
			char want[32];
			snprintf(want, sizeof(want), "%u", c->limits.max_queue);
			assert_string_equal(info.fallback, want);
			assert_string_equal(info.type, "integer from 1 to 10000000");
			have_limit = true;
		}
	}
	assert_true(have_limit);
	settings_free(c);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_defaults),
		cmocka_unit_test(test_full),
		cmocka_unit_test(test_errors),
		cmocka_unit_test(test_syntax_and_missing),
		cmocka_unit_test(test_comments),
		cmocka_unit_test(test_reference),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
