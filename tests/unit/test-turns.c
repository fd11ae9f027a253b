/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The clients' turns (daemon/turns.c) on a real sd-event loop: the order
 * they run in (first come, first served; fresh turns before those that go
 * on, but not more than TURN_FRESH_RUN of them in a row), a turn taken off
 * the queue, a turn that queues itself again.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "turns.h"

struct fixture {
	sd_event *event;
	struct turns *turns;
	char order[64];
	size_t n;
};

struct client {
	struct fixture *f;
	struct turn turn;
	char name;
	int again;              /* slices it still wants after this one */
	bool fresh_again;
};

static void run(void *data)
{
	struct client *c = data;

	c->f->order[c->f->n++] = c->name;
	if (c->again-- > 0)
		turns_queue(c->f->turns, &c->turn, c->fresh_again);
}

static int setup(void **state)
{
	struct fixture *f = calloc(1, sizeof(*f));

	assert_int_equal(sd_event_new(&f->event), 0);
	assert_int_equal(turns_new(f->event, &f->turns), 0);
	*state = f;
	return 0;
}

static int teardown(void **state)
{
	struct fixture *f = *state;

	turns_free(f->turns);
	sd_event_unref(f->event);
	free(f);
	return 0;
}

static void drain(struct fixture *f)
{
	while (turns_waiting(f->turns))
		assert_true(sd_event_run(f->event, 0) >= 0);
	f->order[f->n] = '\0';
}

static struct client client(struct fixture *f, char name, int again)
{
	return (struct client){ .f = f, .name = name, .again = again,
				.turn = { .run = run } };
}

static void test_order(void **state)
{
	struct fixture *f = *state;
	struct client a = client(f, 'a', 2), b = client(f, 'b', 1), c = client(f, 'c', 0);

	a.turn.data = &a;
	b.turn.data = &b;
	c.turn.data = &c;
	/* three long answers going on: round robin */
	turns_queue(f->turns, &a.turn, false);
	turns_queue(f->turns, &b.turn, false);
	turns_queue(f->turns, &a.turn, false);          /* (waits already: nothing) */
	turns_queue(f->turns, &c.turn, false);
	drain(f);
	assert_string_equal(f->order, "abcaba");
}

static void test_fresh_first(void **state)
{
	struct fixture *f = *state;
	struct client longs[2], news[12];

	for (int i = 0; i < 2; i++) {
		longs[i] = client(f, (char)('A' + i), 3);
		longs[i].turn.data = &longs[i];
		turns_queue(f->turns, &longs[i].turn, false);
	}
	/* a short request comes while the long answers take turns: next */
	assert_true(sd_event_run(f->event, 0) >= 0);
	news[0] = client(f, 'n', 0);
	news[0].turn.data = &news[0];
	turns_queue(f->turns, &news[0].turn, true);
	drain(f);
	assert_string_equal(f->order, "AnBABABAB");

	/* a flood of fresh turns lets one that goes on through every
	 * TURN_FRESH_RUN */
	f->n = 0;
	longs[0] = client(f, 'L', 1);
	longs[0].turn.data = &longs[0];
	turns_queue(f->turns, &longs[0].turn, false);
	for (int i = 0; i < 12; i++) {
		news[i] = client(f, (char)('a' + i), 0);
		news[i].turn.data = &news[i];
		turns_queue(f->turns, &news[i].turn, true);
	}
	drain(f);
	assert_int_equal(TURN_FRESH_RUN, 8);
	assert_string_equal(f->order, "abcdefghLijklL");
}

static void test_remove(void **state)
{
	struct fixture *f = *state;
	struct client a = client(f, 'a', 0), b = client(f, 'b', 0), c = client(f, 'c', 0);

	a.turn.data = &a;
	b.turn.data = &b;
	c.turn.data = &c;
	turns_queue(f->turns, &a.turn, true);
	turns_queue(f->turns, &b.turn, false);
	turns_queue(f->turns, &c.turn, true);
	turns_remove(f->turns, &a.turn);
	turns_remove(f->turns, &b.turn);
	turns_remove(f->turns, &b.turn);                /* (not waiting: nothing) */
	drain(f);
	assert_string_equal(f->order, "c");
	assert_false(turns_waiting(f->turns));
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test_setup_teardown(test_order, setup, teardown),
		cmocka_unit_test_setup_teardown(test_fresh_first, setup, teardown),
		cmocka_unit_test_setup_teardown(test_remove, setup, teardown),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
