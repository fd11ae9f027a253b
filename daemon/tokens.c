/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Event loop thread: the named API tokens. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>

#include "asph-proto.h"
#include "log.h"
#include <nettle/memops.h>

#include "util-hash.h"
#include "store.h"
#include "store-sql.h"
#include "tokens.h"
#include "util-mem.h"
#include "util-time.h"

static const char *const role_names[] = {
	[ROLE_NONE] = "none",
	[ROLE_VIEWER] = "viewer",
	[ROLE_OPERATOR] = "operator",
	[ROLE_ADMIN] = "admin",
};

const char *access_role_name(enum access_role r)
{
	return (unsigned)r < ARRAY_SIZE(role_names) ? role_names[r] : "none";
}

int access_role_from_name(const char *name, enum access_role *out)
{
	for (int r = ROLE_VIEWER; r <= ROLE_ADMIN; r++)
		if (!strcmp(role_names[r], name)) {
			*out = (enum access_role)r;
			return 0;
		}
	return -EINVAL;
}

struct token {
	struct token_info info;
	uint8_t digest[32];
	int64_t created_ns;
	char *created_by;
};

struct tokens {
	struct store *store;
	struct token *v;
	size_t n, cap;
	void (*changed)(void *data);
	void *changed_data;
};

/* ------------------------------------ the table tokens in the store */

/* A row: name, role, SHA-256 of the secret. */
struct store_token {
	const char *name;
	int role;
	const uint8_t *digest;  /* 32 bytes */
	int64_t created_ns, expires_ns, revoked_ns;     /* 0: never, not */
	const char *created_by;
};
typedef int (*store_token_fn)(const struct store_token *t, void *data);

/* -EEXIST when a token of that name exists (revoked or not). */
static int store_token_insert(struct store *s, const struct store_token *t)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"INSERT INTO tokens (name, role, digest, created_ns, expires_ns, revoked_ns,"
		" created_by) VALUES (?,?,?,?,?,0,?)");
	int rc;

	if (!st)
		return -EIO;
	store_bind_text(st, 1, t->name);
	sqlite3_bind_int(st, 2, t->role);
	sqlite3_bind_blob(st, 3, t->digest, 32, SQLITE_TRANSIENT);
	sqlite3_bind_int64(st, 4, t->created_ns);
	sqlite3_bind_int64(st, 5, t->expires_ns);
	store_bind_text(st, 6, t->created_by);
	rc = sqlite3_step(st);
	if (rc == SQLITE_DONE)
		return 0;
	return (rc & 0xff) == SQLITE_CONSTRAINT ? -EEXIST : store_errno(rc);
}

static int store_token_list(struct store *s, store_token_fn fn, void *data)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"SELECT name, role, digest, created_ns, expires_ns, revoked_ns, created_by"
		" FROM tokens ORDER BY name");
	int r;

	if (!st)
		return -EIO;
	while ((r = sqlite3_step(st)) == SQLITE_ROW) {
		struct store_token t = {
			.name = (const char *)sqlite3_column_text(st, 0),
			.role = sqlite3_column_int(st, 1),
			.digest = sqlite3_column_blob(st, 2),
			.created_ns = sqlite3_column_int64(st, 3),
			.expires_ns = sqlite3_column_int64(st, 4),
			.revoked_ns = sqlite3_column_int64(st, 5),
			.created_by = (const char *)sqlite3_column_text(st, 6),
		};
		int k;
		if (!t.name || !t.digest || sqlite3_column_bytes(st, 2) != 32)
			continue;
		k = fn(&t, data);
		if (k < 0)
			return k;
	}
	return r == SQLITE_DONE ? 0 : -EIO;
}

/* -ENOENT when there is no such token, -EALREADY when it is revoked. */
static int store_token_revoke(struct store *s, const char *name, int64_t now_ns)
{
	_cleanup_stmt_ sqlite3_stmt *q = store_prepare(s, "SELECT revoked_ns FROM tokens WHERE name = ?");
	_cleanup_stmt_ sqlite3_stmt *st = NULL;
	int r;

	if (!q)
		return -EIO;
	store_bind_text(q, 1, name);
	r = store_step_row(q);
	if (r < 0)
		return r;
	if (sqlite3_column_int64(q, 0) != 0)
		return -EALREADY;
	st = store_prepare(s, "UPDATE tokens SET revoked_ns = ? WHERE name = ?");
	if (!st)
		return -EIO;
	sqlite3_bind_int64(st, 1, now_ns);
	store_bind_text(st, 2, name);
	return store_step_done(st);
}

/* --------------------------------------------------------- the tokens */

static int add(struct tokens *t, const struct store_token *st)
{
	struct token *k;

	if (t->n == t->cap) {
		size_t cap = t->cap ? 2 * t->cap : 8;
		k = realloc(t->v, cap * sizeof(*k));
		if (!k)
			return -ENOMEM;
		t->v = k;
		t->cap = cap;
	}
	k = &t->v[t->n];
	*k = (struct token){ .created_ns = st->created_ns };
	snprintf(k->info.name, sizeof(k->info.name), "%s", st->name);
	k->info.role = st->role >= ROLE_VIEWER && st->role <= ROLE_ADMIN
		? (enum access_role)st->role : ROLE_NONE;
	k->info.expires_ns = st->expires_ns;
	k->info.revoked_ns = st->revoked_ns;
	memcpy(k->digest, st->digest, sizeof(k->digest));
	k->created_by = st->created_by ? strdup(st->created_by) : NULL;
	t->n++;
	return 0;
}

static int load_one(const struct store_token *st, void *data)
{
	return add(data, st);
}

int tokens_open(const char *path, struct tokens **out, struct asph_error *err)
{
	struct tokens *t = calloc(1, sizeof(*t));
	int r;

	if (!t)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = store_open(path, &t->store, err);
	if (r == 0) {
		r = store_token_list(t->store, load_one, t);
		if (r < 0)
			asph_error_set(err, r, "cannot read the API tokens: %s", strerror(-r));
	}
	if (r < 0) {
		tokens_free(t);
		return r;
	}
	*out = t;
	return 0;
}

void tokens_free(struct tokens *t)
{
	if (!t)
		return;
	for (size_t i = 0; i < t->n; i++)
		free(t->v[i].created_by);
	if (t->v)
		explicit_bzero(t->v, t->cap * sizeof(*t->v));
	free(t->v);
	store_close(t->store);
	free(t);
}

void tokens_set_changed(struct tokens *t, void (*fn)(void *data), void *data)
{
	t->changed = fn;
	t->changed_data = data;
}

static bool name_ok(const char *name)
{
	size_t n = strlen(name);

	if (n == 0 || n > TOKENS_NAME_MAX || !strcmp(name, "token_file"))
		return false;
	return strspn(name, "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"
			    "0123456789._@-") == n;
}

/* 32 random bytes as "asph_" and base64url without padding. */
static int make_secret(char secret[TOKENS_SECRET_SIZE])
{
	uint8_t raw[32];
	_cleanup_free_ char *b64 = NULL;
	ssize_t n = getrandom(raw, sizeof(raw), 0);

	if (n != (ssize_t)sizeof(raw))
		return n < 0 ? -errno : -EIO;
	b64 = proto_base64url_encode(raw, sizeof(raw));
	explicit_bzero(raw, sizeof(raw));
	if (!b64)
		return -ENOMEM;
	snprintf(secret, TOKENS_SECRET_SIZE, "asph_%s", b64);
	explicit_bzero(b64, strlen(b64));
	return 0;
}

int tokens_create(struct tokens *t, const char *name, enum access_role role,
		  int64_t expires_ns, const char *creator, char secret[TOKENS_SECRET_SIZE],
		  struct asph_error *err)
{
	struct store_token st = {
		.name = name, .role = (int)role, .created_ns = now_realtime_ns(),
		.expires_ns = expires_ns, .created_by = creator,
	};
	uint8_t digest[32];
	struct sha256_ctx h;
	int r;

	if (!name_ok(name))
		return asph_error_set(err, -EINVAL, "a token's name is 1 to %d letters, digits or "
				      "'._@-' (and not \"token_file\"), not \"%.80s\"",
				      TOKENS_NAME_MAX, name);
	if (expires_ns && expires_ns <= st.created_ns)
		return asph_error_set(err, -EINVAL, "the expiry is in the past");
	for (size_t i = 0; i < t->n; i++)
		if (!strcmp(t->v[i].info.name, name))
			return asph_error_set(err, -EEXIST, "a token named \"%s\" exists%s: pick "
					      "another name", name,
					      t->v[i].info.revoked_ns ? " (revoked)" : "");
	r = make_secret(secret);
	if (r < 0)
		return asph_error_set(err, r, "cannot make a secret: %s", strerror(-r));
	sha256_init(&h);
	sha256_update(&h, strlen(secret), (const uint8_t *)secret);
	sha256_digest(&h, SHA256_DIGEST_SIZE, digest);
	explicit_bzero(&h, sizeof(h));
	st.digest = digest;
	r = store_token_insert(t->store, &st);
	if (r == 0)
		r = add(t, &st);
	if (r < 0) {
		explicit_bzero(secret, TOKENS_SECRET_SIZE);
		return asph_error_set(err, r, "cannot store the token: %s", strerror(-r));
	}
	log_notice("API token \"%s\" (%s%s) created by %s", name, access_role_name(role),
		   expires_ns ? ", expiring" : "", creator);
	if (t->changed)
		t->changed(t->changed_data);
	return 0;
}

int tokens_revoke(struct tokens *t, const char *name, struct asph_error *err)
{
	int64_t now = now_realtime_ns();
	int r = store_token_revoke(t->store, name, now);

	if (r == -ENOENT)
		return asph_error_set(err, r, "no token named \"%.80s\"", name);
	if (r == -EALREADY)
		return asph_error_set(err, r, "the token \"%.80s\" is revoked already", name);
	if (r < 0)
		return asph_error_set(err, r, "cannot revoke the token: %s", strerror(-r));
	for (size_t i = 0; i < t->n; i++)
		if (!strcmp(t->v[i].info.name, name))
			t->v[i].info.revoked_ns = now;
	log_notice("API token \"%s\" revoked", name);
	if (t->changed)
		t->changed(t->changed_data);
	return 0;
}

json_t *tokens_to_json(const struct tokens *t)
{
	int64_t now = now_realtime_ns();
	json_t *list = json_array();

	for (size_t i = 0; list && i < t->n; i++) {
		const struct token *k = &t->v[i];
		const char *state = k->info.revoked_ns ? "revoked"
			: k->info.expires_ns && k->info.expires_ns <= now ? "expired" : "active";
		json_array_append_new(list, json_pack("{s:s, s:s, s:s, s:o, s:s?, s:o, s:o}",
			"name", k->info.name, "role", access_role_name(k->info.role),
			"state", state, "created", proto_time_json(k->created_ns),
			"created_by", k->created_by, "expires", proto_time_json(k->info.expires_ns),
			"revoked", proto_time_json(k->info.revoked_ns)));
	}
	return json_pack("{s:o}", "tokens", list);
}

bool tokens_digest_equal(const uint8_t a[32], const uint8_t b[32])
{
	return memeql_sec(a, b, 32);
}

int tokens_match(const struct tokens *t, const uint8_t digest[32], struct token_info *out)
{
	size_t found = SIZE_MAX;

	/* Every digest in full: no early exit on a match or a difference.
	 * Which token matched is selected without a branch on the data. */
	for (size_t i = 0; i < t->n; i++) {
		size_t hit = (size_t)0 - (size_t)tokens_digest_equal(t->v[i].digest, digest);
		found = (found & ~hit) | (i & hit);
	}
	if (found == SIZE_MAX)
		return -ENOENT;
	*out = t->v[found].info;
	return 0;
}

bool tokens_current(const struct tokens *t, const char *name, const uint8_t digest[32],
		    int64_t now_ns)
{
	for (size_t i = 0; i < t->n; i++) {
		const struct token *k = &t->v[i];
		if (strcmp(k->info.name, name))
			continue;
		return !k->info.revoked_ns && (!k->info.expires_ns || k->info.expires_ns > now_ns) &&
		       tokens_digest_equal(k->digest, digest);
	}
	return false;
}

int64_t tokens_next_expiry(const struct tokens *t, int64_t now_ns)
{
	int64_t next = 0;

	for (size_t i = 0; i < t->n; i++) {
		int64_t e = t->v[i].info.expires_ns;
		if (!t->v[i].info.revoked_ns && e > now_ns && (!next || e < next))
			next = e;
	}
	return next;
}
