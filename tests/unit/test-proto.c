/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "asph-proto.h"

static void feed(struct proto_lines *l, const char *s)
{
	char *dst;
	size_t n = strlen(s);

	assert_int_equal(proto_lines_reserve(l, n, &dst), 0);
	memcpy(dst, s, n);
	proto_lines_commit(l, n);
}

static void test_lines_split(void **state)
{
	struct proto_lines l;
	char *line;
	size_t n;

	proto_lines_init(&l, 64);
	feed(&l, "{\"a\":1}\n{\"b\"");
	assert_int_equal(proto_lines_next(&l, &line, &n), 1);
	assert_string_equal(line, "{\"a\":1}");
	assert_int_equal(n, 7);
	assert_int_equal(proto_lines_next(&l, &line, &n), 0);
	assert_int_equal(proto_lines_pending(&l), 4);
	feed(&l, ":2}\r\n\n");
	assert_int_equal(proto_lines_next(&l, &line, &n), 1);
	assert_string_equal(line, "{\"b\":2}");
	assert_int_equal(proto_lines_next(&l, &line, &n), 1);
	assert_int_equal(n, 0);
	assert_int_equal(proto_lines_next(&l, &line, &n), 0);
	assert_int_equal(proto_lines_pending(&l), 0);
	proto_lines_release(&l);
}

/* A line over the limit is reported once, whether it arrives whole or in
 * pieces, and the next line comes through intact. */
static void test_lines_oversized(void **state)
{
	struct proto_lines l;
	char big[200], *line;
	size_t n;

	memset(big, 'x', sizeof(big) - 1);
	big[sizeof(big) - 1] = '\0';
	proto_lines_init(&l, 37);
	feed(&l, big);
	assert_int_equal(proto_lines_next(&l, &line, &n), -EMSGSIZE);
	feed(&l, big);
	assert_int_equal(proto_lines_next(&l, &line, &n), 0);
	feed(&l, "tail\nok-line\n");
	assert_int_equal(proto_lines_next(&l, &line, &n), 1);
	assert_string_equal(line, "ok-line");
	/* exactly at the limit passes, one more byte does not */
	char at[39];
	memset(at, 'y', 37);
	at[37] = '\n';
	at[38] = '\0';
	feed(&l, at);
	assert_int_equal(proto_lines_next(&l, &line, &n), 1);
	assert_int_equal(n, 37);
	feed(&l, "z");
	feed(&l, at);
	assert_int_equal(proto_lines_next(&l, &line, &n), -EMSGSIZE);
	assert_int_equal(proto_lines_next(&l, &line, &n), 0);
	proto_lines_release(&l);
}

static int check(const char *text, struct proto_message *m, struct proto_why *why)
{
	struct proto_why parse_why;
	json_t *j = proto_parse(text, strlen(text), &parse_why);
	int r;

	assert_non_null(j);
	r = proto_check_request(j, m, why);
	json_decref(j);
	return r;
}

static void test_requests(void **state)
{
	struct proto_message m;
	struct proto_why why;

	assert_int_equal(check("{\"jsonrpc\":\"2.0\",\"id\":7,\"method\":\"hello\"}", &m, &why), 0);
	assert_int_equal(m.kind, PROTO_KIND_REQUEST);
	assert_int_equal(check("{\"jsonrpc\":\"2.0\",\"method\":\"x\",\"params\":[1]}", &m, &why), 0);
	assert_int_equal(m.kind, PROTO_KIND_NOTIFICATION);
	assert_int_equal(check("{\"jsonrpc\":\"1.0\",\"id\":1,\"method\":\"x\"}", &m, &why),
			 PROTO_INVALID_REQUEST);
	assert_non_null(m.id);
	assert_int_equal(check("{\"jsonrpc\":\"2.0\",\"id\":{},\"method\":\"x\"}", &m, &why),
			 PROTO_INVALID_REQUEST);
	assert_null(m.id);
	assert_int_equal(check("{\"jsonrpc\":\"2.0\",\"id\":\"a\",\"method\":3}", &m, &why),
			 PROTO_INVALID_REQUEST);
	assert_int_equal(check("{\"jsonrpc\":\"2.0\",\"id\":2,\"method\":\"x\",\"params\":5}", &m, &why),
			 PROTO_INVALID_REQUEST);
	assert_int_equal(check("[1]", &m, &why), PROTO_INVALID_REQUEST);
	/* A NUL inside the method name does not cut it to a known one. */
	assert_int_equal(check("{\"jsonrpc\":\"2.0\",\"id\":3,\"method\":\"hello\\u0000x\"}", &m, &why),
			 PROTO_INVALID_REQUEST);
	assert_non_null(strstr(why.text, "NUL"));
	assert_non_null(m.id);

	/* The unknown member is named (borrowed from the message). */
	json_t *j = json_pack("{s:s, s:i, s:s, s:{}}", "jsonrpc", "2.0", "id", 4, "method", "x",
			      "Params");
	assert_int_equal(proto_check_request(j, &m, &why), PROTO_INVALID_REQUEST);
	assert_non_null(m.unknown);
	assert_string_equal(m.unknown, "Params");
	json_decref(j);

	struct proto_why pw;
	assert_null(proto_parse("{\"a\":1,\"a\":2}", 13, &pw));
	assert_null(proto_parse("{\"a\":", 5, &pw));
	assert_non_null(strstr(pw.text, "column"));
	assert_null(proto_parse("{\"a\":", 5, NULL));
	/* jansson quotes the text near the error: the message is valid
	 * UTF-8 */
	const char *bad = "{\"a\": x\xc3\xa9\xc3\xa9\xc3\xa9\xc3\xa9}";
	assert_null(proto_parse(bad, strlen(bad), &pw));
	json_t *str = json_string(pw.text);
	assert_non_null(str);
	json_decref(str);
	/* cut to fit inside a character, it stays valid UTF-8 */
	char long_text[601];
	for (int i = 0; i < 300; i++)
		memcpy(long_text + 2 * i, "\xc3\xa9", 2);
	long_text[600] = '\0';
	assert_int_equal(proto_why_set(&pw, "%s", long_text), -EINVAL);
	assert_int_equal(strlen(pw.text), 254);
	str = json_string(pw.text);
	assert_non_null(str);
	json_decref(str);
	assert_int_equal(proto_why_set(NULL, "x"), -EINVAL);
}

/* A UTF-8 byte-order mark is skipped at the start of a line only; the
 * column of an error counts it. */
static void test_byte_order_mark(void **state)
{
	struct proto_why why;
	json_t *j = proto_parse("\xef\xbb\xbf{\"a\": 1}", 11, &why);

	assert_non_null(j);
	assert_int_equal(json_integer_value(json_object_get(j, "a")), 1);
	json_decref(j);
	/* The fault is the third character of the line as sent. */
	assert_null(proto_parse("\xef\xbb\xbf{,}", 6, &why));
	assert_true(strncmp(why.text, "column 3: ", 10) == 0);
	assert_null(proto_parse("\xef\xbb\xbf\xef\xbb\xbf{}", 8, &why));
	assert_true(strncmp(why.text, "column 2: ", 10) == 0);
	assert_null(proto_parse(" \xef\xbb\xbf{}", 6, &why));
	assert_true(strncmp(why.text, "column 2: ", 10) == 0);
	assert_null(proto_parse("\xef\xbb\xbf", 3, &why));
	assert_null(proto_parse("\xef\xbb", 2, &why));
}

static void test_utf8_clean(void **state)
{
	char cut[] = "no method \"\xc3\xa9\xc3\"";
	char bad[] = "a" "\xc0\xaf" "b" "\xed\xa0\x80" "c" "\xf4\x90\x80\x80" "d" "\x80" "e"
		     "\xe2\x82";
	char good[] = "\xc3\xa9\xe2\x82\xac\xf0\x9f\x98\x80 ok";

	assert_int_equal(proto_utf8_clean(cut), strlen("no method \"\xc3\xa9\""));
	assert_string_equal(cut, "no method \"\xc3\xa9\"");
	/* Overlong form, surrogate, past U+10FFFF, lone continuation byte,
	 * truncated sequence: each dropped. */
	proto_utf8_clean(bad);
	assert_string_equal(bad, "abcde");
	assert_int_equal(proto_utf8_clean(good), strlen("\xc3\xa9\xe2\x82\xac\xf0\x9f\x98\x80 ok"));
}

static void test_builders(void **state)
{
	json_t *id = json_integer(41);
	json_t *r = proto_make_error(id, PROTO_NO_SUCH_JOB, NULL, json_pack("{s:i}", "job", 9));
	size_t n;
	char *s = proto_dump(r, &n);
	struct proto_message m;
	struct proto_why why;

	assert_non_null(s);
	assert_int_equal(s[n - 1], '\n');
	assert_int_equal(strlen(s), n);
	assert_non_null(strstr(s, "\"No such job\""));
	assert_int_equal(proto_check_incoming(r, &m, &why), 0);
	assert_int_equal(m.kind, PROTO_KIND_RESPONSE);
	assert_int_equal(m.error_code, 101);
	free(s);
	json_decref(r);

	r = proto_make_result(id, json_pack("{s:s}", "k", "v"));
	assert_int_equal(proto_check_incoming(r, &m, &why), 0);
	assert_null(m.error);
	assert_string_equal(json_string_value(json_object_get(m.result, "k")), "v");
	json_decref(r);
	r = proto_make_error(NULL, PROTO_PARSE_ERROR, NULL, NULL);
	assert_true(json_is_null(json_object_get(r, "id")));
	json_decref(r);
	json_decref(id);
	assert_string_equal(proto_error_message(-32601), "Method not found");
}

static void test_params(void **state)
{
	json_t *p = json_pack("{s:I, s:f, s:s, s:b, s:[s,s], s:s#}", "n", (json_int_t)17, "x", 2.5,
			      "s", "abc", "b", 1, "ev", "job", "progress", "nul", "a\0b", (size_t)3);
	struct proto_why why;
	int64_t n = 0;
	double x = 0;
	const char *s = NULL;
	bool b = false;
	unsigned mask = 0;
	static const char *const ev[] = { "job", "instrument", "progress", NULL };
	static const char *const only[] = { "n", "x", "s", "b", "ev", NULL };

	assert_int_equal(proto_param_int(p, "n", true, 0, 100, &n, &why), 0);
	assert_int_equal(n, 17);
	assert_int_equal(proto_param_int(p, "n", true, 20, 100, &n, &why), -EINVAL);
	assert_non_null(strstr(why.text, "\"n\""));
	assert_int_equal(proto_param_int(p, "x", true, 0, 100, &n, &why), -EINVAL);
	assert_int_equal(proto_param_number(p, "x", true, 0, 3, &x, &why), 0);
	assert_true(x == 2.5);
	assert_int_equal(proto_param_string(p, "s", true, 8, &s, &why), 0);
	assert_string_equal(s, "abc");
	assert_int_equal(proto_param_string(p, "s", true, 2, &s, &why), -EINVAL);
	assert_int_equal(proto_param_string(p, "nul", true, 8, &s, &why), -EINVAL);
	assert_int_equal(proto_param_bool(p, "b", true, &b, &why), 0);
	assert_true(b);
	assert_int_equal(proto_param_bool(p, "absent", false, &b, &why), -ENOENT);
	assert_int_equal(proto_param_bool(p, "absent", true, &b, &why), -EINVAL);
	assert_int_equal(proto_param_flags(p, "ev", true, ev, &mask, &why), 0);
	assert_int_equal(mask, 5u);
	assert_int_equal(proto_params_only(p, only, &why), -EINVAL);
	assert_non_null(strstr(why.text, "nul"));
	json_decref(p);
	assert_int_equal(proto_param_int(NULL, "n", false, 0, 1, &n, &why), -ENOENT);

	/* null is a wrong type, not an absent member; a NUL inside a flag
	 * does not cut it to a known one. */
	p = json_pack("{s:n, s:[s]}", "opt", "ev", "job\0x");
	json_array_set_new(json_object_get(p, "ev"), 0, json_stringn("job\0x", 5));
	assert_int_equal(proto_param_bool(p, "opt", false, &b, &why), -EINVAL);
	assert_non_null(strstr(why.text, "\"opt\""));
	assert_int_equal(proto_param_int(p, "opt", true, 0, 1, &n, &why), -EINVAL);
	assert_non_null(strstr(why.text, "must be an integer"));
	assert_int_equal(proto_param_flags(p, "ev", true, ev, &mask, &why), -EINVAL);
	assert_non_null(strstr(why.text, "NUL"));
	json_decref(p);
}

/* RFC 4648 §10's vectors; base64url for tokens and cookies (§5), unpadded. */
static void test_base64(void **state)
{
	static const char *plain[] = { "", "f", "fo", "foo", "foob", "fooba", "foobar" };
	static const char *coded[] = { "", "Zg==", "Zm8=", "Zm9v", "Zm9vYg==", "Zm9vYmE=", "Zm9vYmFy" };
	const uint8_t url[] = { 0xfb, 0xff, 0xbf, 0x3e };
	void *back;
	size_t n;

	(void)state;
	for (size_t i = 0; i < sizeof(plain) / sizeof(plain[0]); i++) {
		char *b = proto_base64_encode(plain[i], strlen(plain[i]));
		assert_string_equal(b, coded[i]);
		free(b);
		assert_int_equal(proto_base64_decode(coded[i], strlen(coded[i]), &back, &n), 0);
		assert_int_equal(n, strlen(plain[i]));
		assert_memory_equal(back, plain[i], n);
		free(back);
	}
	char *u = proto_base64url_encode(url, sizeof(url));
	assert_string_equal(u, "-_-_Pg");
	free(u);
	/* not the protocol's base64: unpadded, white space, another alphabet, junk after '=' */
	static const char *bad[] = { "Zg", "Zm 9", "-_-_", "Zg=A", "Z===" };
	for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++)
		assert_int_equal(proto_base64_decode(bad[i], strlen(bad[i]), &back, &n), -EINVAL);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_lines_split),
		cmocka_unit_test(test_lines_oversized),
		cmocka_unit_test(test_requests),
		cmocka_unit_test(test_byte_order_mark),
		cmocka_unit_test(test_utf8_clean),
		cmocka_unit_test(test_builders),
		cmocka_unit_test(test_params),
		cmocka_unit_test(test_base64),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
