/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <link.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "umockdev-util.h"

static int find_preload(struct dl_phdr_info *info, size_t size, void *data)
{
	bool *found = data;

	(void)size;
	if (info->dlpi_name && strstr(info->dlpi_name, "libumockdev-preload"))
		*found = true;
	return 0;
}

UMockdevTestbed *umt_testbed_new(void)
{
	bool preload = false;

	dl_iterate_phdr(find_preload, &preload);
	if (!preload) {
		fprintf(stderr, "SKIP: libumockdev-preload is not loaded in this process "
			"(link with -Wl,--no-as-needed -lumockdev-preload)\n");
		exit(77);
	}
	return umockdev_testbed_new();
}

void umt_add(UMockdevTestbed *tb, const char *description)
{
	GError *e = NULL;

	if (!umockdev_testbed_add_from_string(tb, description, &e)) {
		fprintf(stderr, "umockdev: cannot add device: %s\n", e->message);
		g_error_free(e);
		exit(1);
	}
}

void umt_attach(UMockdevTestbed *tb, const char *devnode, UMockdevIoctlBase *h)
{
	GError *e = NULL;

	if (!umockdev_testbed_attach_ioctl(tb, devnode, h, &e)) {
		fprintf(stderr, "umockdev: cannot attach to %s: %s\n", devnode, e->message);
		g_error_free(e);
		exit(1);
	}
}

uint8_t *umt_arg(UMockdevIoctlClient *c, size_t *len)
{
	UMockdevIoctlData *d = umockdev_ioctl_client_get_arg(c);

	*len = (size_t)d->data_len;
	return d->data;
}

UMockdevIoctlData *umt_arg_resolve(UMockdevIoctlClient *c, size_t offset, size_t len)
{
	GError *e = NULL;
	UMockdevIoctlData *d = umockdev_ioctl_data_resolve(umockdev_ioctl_client_get_arg(c),
							    offset, len, &e);

	if (!d) {
		fprintf(stderr, "umockdev: cannot resolve an ioctl argument: %s\n", e->message);
		g_error_free(e);
		exit(1);
	}
	return d;
}
