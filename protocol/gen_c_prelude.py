"""The C codec's fixed prelude (protocol/generate.py): little-endian field access and the CRC-32C."""

from __future__ import annotations


def crc_table(bits: int = 8) -> list[int]:
    """Entry n: the CRC register after shifting the `bits`-bit value n through `bits` steps."""
    poly = 0x82F63B78  # reflected Castagnoli polynomial
    table = []
    for i in range(1 << bits):
        c = i
        for _ in range(bits):
            c = (c >> 1) ^ poly if c & 1 else c >> 1
        table.append(c)
    return table


def c_byte_order() -> list[str]:
    """Little-endian field access that works on any host byte order (one load or store where allowed)."""
    return [
         "/* Little-endian field access that works on any host byte order. */",
         "static uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }",
         "static uint32_t get_u32(const uint8_t *p)",
         "{",
         "#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__",
         "    uint32_t v; /* one load where unaligned loads are allowed (Cortex-M4, x86), bytes elsewhere */",
         "    memcpy(&v, p, sizeof v);",
         "    return v;",
         "#else",
         "    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);",
         "#endif",
         "}",
         "static uint64_t get_u64(const uint8_t *p) { return (uint64_t)get_u32(p) | ((uint64_t)get_u32(p + 4) << 32); }",
         "static float get_f32(const uint8_t *p)",
         "{",
         "    uint32_t u = get_u32(p);",
         "    float f;",
         "    memcpy(&f, &u, sizeof f);",
         "    return f;",
         "}",
         "static void put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }",
         "static void put_u32(uint8_t *p, uint32_t v)",
         "{",
         "#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__",
         "    memcpy(p, &v, sizeof v);",
         "#else",
         "    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);",
         "#endif",
         "}",
         "static void put_u64(uint8_t *p, uint64_t v) { put_u32(p, (uint32_t)v); put_u32(p + 4, (uint32_t)(v >> 32)); }",
         "static void put_f32(uint8_t *p, float f)",
         "{",
         "    uint32_t u;",
         "    memcpy(&u, &f, sizeof u);",
         "    put_u32(p, u);",
         "}"]


def c_finite() -> list[str]:
    """isfinite() of a float from its bits (exponent not all ones): integer instructions, where the VFP compare and
    the FPSCR read it compiles to cost an emulator a helper call each."""
    return ["/* Finite: the exponent bits are not all ones (not an infinity, not a NaN), as isfinite(). */",
            "static int f32_finite(float f)",
            "{",
            "    uint32_t u;",
            "    memcpy(&u, &f, sizeof u);",
            "    return (u & 0x7F800000u) != 0x7F800000u;",
            "}", ""]


def c_crc32c() -> list[str]:
    """The CRC-32C nibble table (64 bytes, const: in flash), the byte table built from it in RAM on first use,
    and the word-at-a-time function over the byte table."""
    table = crc_table(4)
    rows = [", ".join(f"0x{v:08X}u" for v in table[i:i + 8]) for i in range(0, 16, 8)]
    nibble_step = "c = crc32c_nibble[c & 0xFu] ^ (c >> 4);"
    byte_step = "crc = crc32c_byte[crc & 0xFFu] ^ (crc >> 8);"
    o = [
         "/* Reflected Castagnoli polynomial 0x82F63B78, four bits per step: entry n is the CRC register after",
         " * shifting nibble n through four steps (64 bytes of flash instead of a 1 KiB const table). */",
         "static const uint32_t crc32c_nibble[16] = {"]
    o += [f"    {r}," for r in rows]
    o += ["};", "",
          "/* Eight bits per step: entry n is two nibble steps of n. Built in RAM (1 KiB of .bss, no flash) on the first",
          " * CRC: half the instructions of nibble steps on every frame received and sent. Entry 1 is never 0 once",
          " * built; building it again (an interrupted first build) writes the same values. */",
          "static uint32_t crc32c_byte[256];",
          "",
          "static void crc32c_build(void)",
          "{",
          "    uint32_t b;",
          "    for (b = 0; b < 256u; b++) {",
          "        uint32_t c = b;",
          f"        {nibble_step}",
          f"        {nibble_step}",
          "        crc32c_byte[b] = c;",
          "    }",
          "}",
          "",
          "/* A little-endian word at a time (reflected CRC: XOR it in, then four byte steps), the tail bytewise. */",
          "uint32_t uwb_crc32c(const uint8_t *data, size_t n)",
          "{",
          "    uint32_t crc = 0xFFFFFFFFu;",
          "    size_t i = 0;",
          "    if (crc32c_byte[1] == 0u) {",
          "        crc32c_build();",
          "    }",
          "    for (; i + 4u <= n; i += 4u) {",
          "        crc ^= get_u32(data + i);"]
    o += [f"        {byte_step}"] * 4
    o += ["    }",
          "    for (; i < n; i++) {",
          "        crc ^= data[i];",
          f"        {byte_step}",
          "    }",
          "    return crc ^ 0xFFFFFFFFu;",
          "}", ""]
    return o
