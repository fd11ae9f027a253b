/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What the web listener reads of a request itself (daemon/web.c): the
 * Origin rule, the counts and job routes of its paths, the names of the
 * files it serves, the login body. The listener as a whole is tested
 * against a real daemon by tests/integration/test-daemon-web.py.
 */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "web.h"

static void test_origin(void **state)
{
	/* not a browser: no Origin, no Sec-Fetch-Site */
	assert_true(web_origin_allowed(NULL, "127.0.0.1:7718", NULL));
	assert_true(web_origin_allowed(NULL, NULL, NULL));
	assert_true(web_origin_allowed("http://127.0.0.1:7718", "127.0.0.1:7718", "same-origin"));
	/* through a TLS proxy that passes Host on; the host without case */
	assert_true(web_origin_allowed("https://Metrology.Lab.example", "metrology.lab.example", NULL));
	assert_true(web_origin_allowed("http://a:1", "a:1", "none"));

	assert_false(web_origin_allowed("http://evil.example", "127.0.0.1:7718", NULL));
	assert_false(web_origin_allowed("http://127.0.0.1:7719", "127.0.0.1:7718", NULL));
	assert_false(web_origin_allowed("http://127.0.0.1:7718.evil", "127.0.0.1:7718", NULL));
	assert_false(web_origin_allowed("http://127.0.0.1", "127.0.0.1:7718", NULL));
	assert_false(web_origin_allowed("null", "127.0.0.1:7718", NULL));
	assert_false(web_origin_allowed("ftp://a:1", "a:1", NULL));
	assert_false(web_origin_allowed("a:1", "a:1", NULL));
	assert_false(web_origin_allowed("http://a:1", NULL, NULL));
	assert_false(web_origin_allowed("", "", NULL));
	/* the browser's own word wins over a matching Origin */
	assert_false(web_origin_allowed("http://a:1", "a:1", "cross-site"));
	assert_false(web_origin_allowed("http://a:1", "a:1", "same-site"));
	assert_false(web_origin_allowed(NULL, "a:1", "cross-site"));
}

static void test_count(void **state)
{
	int64_t v = -1;

	assert_true(web_parse_count("1", 1, &v));
	assert_int_equal(v, 1);
	assert_true(web_parse_count("123456789012345678", 18, &v));
	assert_int_equal(v, 123456789012345678);
	assert_true(web_parse_count("42/x", 2, &v));
	assert_int_equal(v, 42);
	v = 7;
	assert_false(web_parse_count("", 0, &v));
	assert_false(web_parse_count("0", 1, &v));
	assert_false(web_parse_count("01", 2, &v));
	assert_false(web_parse_count("-1", 2, &v));
	assert_false(web_parse_count("+1", 2, &v));
	assert_false(web_parse_count("1x", 2, &v));
	assert_false(web_parse_count("1234567890123456789", 19, &v));      /* could wrap */
	assert_int_equal(v, 7);
}

static void test_job_route(void **state)
{
	const char *rest = NULL;
	int64_t id = 0;

	assert_int_equal(web_job_route("12/files/residuals.csv", &id, &rest), 0);
	assert_int_equal(id, 12);
	assert_string_equal(rest, "/files/residuals.csv");
	assert_int_equal(web_job_route("3/points", &id, &rest), 0);
	assert_string_equal(rest, "/points");
	assert_int_equal(web_job_route("12", &id, &rest), -ENOENT);
	assert_int_equal(web_job_route("/points", &id, &rest), -ENOENT);
	assert_int_equal(web_job_route("0/points", &id, &rest), -ENOENT);
	assert_int_equal(web_job_route("1e3/points", &id, &rest), -ENOENT);
	assert_int_equal(web_job_route("", &id, &rest), -ENOENT);
}

static void test_plain_name(void **state)
{
	char longest[130];

	assert_true(web_plain_name("index.html"));
	assert_true(web_plain_name("residual-map.png"));
	assert_true(web_plain_name("scan.asphscan"));
	assert_false(web_plain_name(""));
	assert_false(web_plain_name("."));
	assert_false(web_plain_name(".."));
	assert_false(web_plain_name(".hidden"));
	assert_false(web_plain_name("../jobs.sqlite"));
	assert_false(web_plain_name("a/b"));
	assert_false(web_plain_name("a b"));
	assert_false(web_plain_name("a%2fb"));
	memset(longest, 'a', 128);
	longest[128] = '\0';
	assert_true(web_plain_name(longest));
	longest[128] = 'a';
	longest[129] = '\0';
	assert_false(web_plain_name(longest));
}

static void check_login(const char *body, const char *want)
{
	json_t *doc = NULL;
	json_t *token = web_login_token(body, body ? strlen(body) : 0, &doc);

	if (want)
		assert_string_equal(json_string_value(token), want);
	else
		assert_null(token);
	json_decref(doc);
}

static void test_login_body(void **state)
{
	check_login("{\"token\": \"asph_x\"}", "asph_x");
	check_login(" {\"token\":\"\"} ", "");
	check_login(NULL, NULL);
	check_login("", NULL);
	check_login("{", NULL);
	check_login("[]", NULL);
	check_login("\"asph_x\"", NULL);
	check_login("{\"token\": 5}", NULL);
	check_login("{\"token\": null}", NULL);
	check_login("{\"token\": \"a\", \"user\": \"b\"}", NULL);
	check_login("{\"token\": \"a\", \"token\": \"b\"}", NULL);
	check_login("{\"Token\": \"a\"}", NULL);
}

static void test_host(void **state)
{
	char *const allowed[] = { "localhost", "127.0.0.1", "::1", "metrology.lab.example", NULL };

	/* the names served, with or without the port, without case */
	assert_true(web_host_allowed("127.0.0.1:7718", allowed));
	assert_true(web_host_allowed("localhost", allowed));
	assert_true(web_host_allowed("LocalHost:80", allowed));
	assert_true(web_host_allowed("[::1]:7718", allowed));
	assert_true(web_host_allowed("[::1]", allowed));
	assert_true(web_host_allowed("::1", allowed));          /* a bare address, as some send */
	assert_true(web_host_allowed("::1:7718", allowed));
	assert_true(web_host_allowed("metrology.lab.example.", allowed));
	/* no Host: an HTTP/1.0 client, not a browser */
	assert_true(web_host_allowed(NULL, allowed));

	/* another name resolving here (DNS rebinding) */
	assert_false(web_host_allowed("evil.example:7718", allowed));
	assert_false(web_host_allowed("evil.example", allowed));
	assert_false(web_host_allowed("127.0.0.1.evil.example", allowed));
	assert_false(web_host_allowed("localhost.evil", allowed));
	assert_false(web_host_allowed("localhost:80x", allowed));
	assert_false(web_host_allowed("[::1]x", allowed));
	assert_false(web_host_allowed("[::1", allowed));
	assert_false(web_host_allowed("[127.0.0.2]:1", allowed));
	assert_false(web_host_allowed("", allowed));
	assert_false(web_host_allowed(":7718", allowed));
	assert_false(web_host_allowed(".", allowed));
	assert_false(web_host_allowed("localhost", (char *const[]){ NULL }));
}

/* "Authorization: Bearer TOKEN" (RFC 6750, 2.1): the scheme in any case,
 * blanks around, one token of visible ASCII; nothing else. */
static void test_bearer(void **state)
{
	static const char *const bad[] = {
		NULL, "", "Bearer", "Bearer ", "Bearer    ", "Basic dXNlcjpwdw==", "Bearerasph_x",
		"Bearer two tokens", "Bearer tab\there", "Bearer caf\xc3\xa9", "Token asph_x",
		"Bearer 0123456789abcdefghijklmnopqrstuvwxyz0123456789abcdefghijklmnopqrstuvwxyz",
	};
	char token[64];

	assert_true(web_bearer_token("Bearer asph_Kq8vT2mX", token, sizeof(token)));
	assert_string_equal(token, "asph_Kq8vT2mX");
	assert_true(web_bearer_token("bearer   a.b-c_d~e+f/g==  ", token, sizeof(token)));
	assert_string_equal(token, "a.b-c_d~e+f/g==");
	assert_true(web_bearer_token("BEARER x", token, sizeof(token)));
	assert_string_equal(token, "x");
	for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++)
		assert_false(web_bearer_token(bad[i], token, sizeof(token)));
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_host),
		cmocka_unit_test(test_origin),
		cmocka_unit_test(test_count),
		cmocka_unit_test(test_job_route),
		cmocka_unit_test(test_plain_name),
		cmocka_unit_test(test_login_body),
		cmocka_unit_test(test_bearer),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
