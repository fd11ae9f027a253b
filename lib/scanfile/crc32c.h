/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * CRC-32C (Castagnoli, reflected polynomial 0x82F63B78), as in iSCSI, ext4
 * and btrfs metadata. Check value: crc32c(0, "123456789", 9) = 0xe3069283.
 * Internal.
 */
#ifndef ASPH_CRC32C_H
#define ASPH_CRC32C_H

#include <stddef.h>
#include <stdint.h>

/* Continues crc over len bytes; start with crc = 0. Uses the SSE 4.2
 * instruction where the processor has it. */
uint32_t crc32c(uint32_t crc, const void *data, size_t len);

/* The same, always from the table (portable path; tests compare both). */
uint32_t crc32c_portable(uint32_t crc, const void *data, size_t len);

#endif
