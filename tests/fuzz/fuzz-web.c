/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What the web listener reads of a request itself (web.h): the input is
 * split at its first two NUL bytes into an Origin, a Host and the rest,
 * which is also taken as a path after /api/jobs/, a file name, a count, a
 * login body and an Authorization header. libmicrohttpd parses the HTTP
 * around them.
 */
#include <stdlib.h>
#include <string.h>

#include "fuzz.h"
#include "web.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	char *text = malloc(size + 1), *origin, *host, *rest, *end;
	char token[64];
	const char *tail;
	json_t *doc = NULL;
	int64_t v;

	if (!text)
		return 0;
	memcpy(text, data, size);
	text[size] = '\0';
	end = text + size;
	origin = text;
	host = origin + strlen(origin);
	host = host < end ? host + 1 : host;
	rest = host + strlen(host);
	rest = rest < end ? rest + 1 : rest;

	(void)web_host_allowed(host, (char *const[]){ "localhost", origin, rest, NULL });
	(void)web_origin_allowed(origin, host, NULL);
	(void)web_origin_allowed(origin, host, rest);
	if (web_job_route(rest, &v, &tail) == 0 && (v <= 0 || *tail != '/'))
		abort();
	(void)web_plain_name(rest);
	if (web_parse_count(rest, strlen(rest), &v) && v <= 0)
		abort();
	(void)web_login_token(rest, (size_t)(end - rest), &doc);
	if (web_bearer_token(rest, token, sizeof(token)) &&
	    (!token[0] || strlen(token) >= sizeof(token) || strchr(token, ' ') ||
	     !strstr(rest, token)))
		abort();
	json_decref(doc);
	free(text);
	return 0;
}
