/* The table of measurement kinds: the rows that mm_table.h lists (generated), by kind code. */
#include "mm_kinds.h"

#include <string.h>

#define MM_ROW_POINTER(name) &mm_kind_##name,
static const mm_kind_t *const rows[] = {MM_KIND_ROWS(MM_ROW_POINTER)};

const mm_kind_t *mm_kind(uint8_t kind)
{
    size_t i;
    for (i = 0; i < sizeof rows / sizeof rows[0]; i++) {
        if (rows[i]->kind == kind) {
            return rows[i];
        }
    }
    return NULL;
}

float mm_cfg(const estimator_config_t *cfg, size_t off)
{
    float v;
    memcpy(&v, (const char *)cfg + off, sizeof v);
    return v;
}
