/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The device and network access the configured instruments need, written
 * as a systemd drop-in or as udev rules (asphd --device-policy): the unit
 * and the rules installed with asphd allow every serial adapter, hidraw
 * node and USBTMC device, which a site can narrow to what its
 * configuration names. Options are read by their names, whatever the
 * driver: "device" and "path" (a node under /dev), "host" (an address
 * for IPAddressAllow=), "vendor_id" and "product_id" (a USB device for a
 * udev rule). Loop thread, at start.
 */
#ifndef ASPHD_DEVICES_H
#define ASPHD_DEVICES_H

#include <stdio.h>

#include "instruments.h"

/* kind "systemd" or "udev"; -EINVAL for another kind. */
int devices_policy(const struct instruments *ins, const char *kind, FILE *out);

#endif
