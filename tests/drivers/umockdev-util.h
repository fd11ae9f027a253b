/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Emulated devices for the driver tests, on umockdev. A test links
 * libumockdev-preload first (tests/drivers/meson.build), so the real
 * hidapi and libusb code runs in the test process against a testbed: its
 * sysfs tree, its device nodes, and a handler in the test that answers the
 * node's ioctl(), read() and write().
 *
 * Handlers run on umockdev's worker thread: state they share with the
 * test needs a lock or atomics. poll() is not emulated: a node with
 * contents is a regular file and always reads as ready, so a handler
 * with nothing to say answers read() with EAGAIN.
 */
#ifndef ASPH_TEST_UMOCKDEV_UTIL_H
#define ASPH_TEST_UMOCKDEV_UTIL_H

#include <stddef.h>
#include <stdint.h>

#include <umockdev.h>

/*
 * A new testbed. Exits 77 with the reason when emulation cannot work in
 * this process: libumockdev-preload is not loaded (the test was not
 * linked with it). The preload works under valgrind and ASan alike.
 */
UMockdevTestbed *umt_testbed_new(void);

/* umockdev_testbed_add_from_string(); exits 1 with the reason on error. */
void umt_add(UMockdevTestbed *tb, const char *description);

/* Routes the ioctl/read/write of devnode ("/dev/...") to handler h. */
void umt_attach(UMockdevTestbed *tb, const char *devnode, UMockdevIoctlBase *h);

/* The buffer of the client's request: the ioctl argument (a pointer
 * value for pointer ioctls), the bytes written, or the buffer to read
 * into; *len is its length. */
uint8_t *umt_arg(UMockdevIoctlClient *c, size_t *len);

/* The len bytes the pointer at offset of the ioctl argument points to
 * (g_object_unref when done); changes are copied back on completion. */
UMockdevIoctlData *umt_arg_resolve(UMockdevIoctlClient *c, size_t offset, size_t len);

#endif
