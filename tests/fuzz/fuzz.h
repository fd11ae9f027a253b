/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Shared by the fuzz targets: the libFuzzer entry points and checks of what
 * every parser promises (a refused input comes with a code and a message).
 */
#ifndef ASPH_FUZZ_H
#define ASPH_FUZZ_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <stdarg.h>

#include "asph/error.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerInitialize(int *argc, char ***argv);

/* A broken promise: report it and abort, so the fuzzer keeps the input. */
static inline __attribute__((noreturn, format(printf, 1, 2)))
void fuzz_die(const char *fmt, ...)
{
	va_list ap;

	va_start(ap, fmt);
	vfprintf(stderr, fmt, ap);
	va_end(ap);
	fputc('\n', stderr);
	abort();
}

/* A parser that refuses an input says why. */
static inline void fuzz_check_error(const struct asph_error *err)
{
	if (err->code >= 0 || err->message[0] == '\0')
		fuzz_die("refused without a reason (code %d)", err->code);
}

#endif
