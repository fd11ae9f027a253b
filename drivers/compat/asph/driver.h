/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The include line of plugins written before the driver ABI's header had a
 * prefix of its own: #include <asph/driver.h> still builds them, the same
 * header. New code includes <asph-driver/driver.h> (docs/drivers.md).
 * Installed only: the tree itself never includes it.
 */
#ifndef ASPH_DRIVER_COMPAT_H
#define ASPH_DRIVER_COMPAT_H

#include "asph-driver/driver.h"

#endif
