/* source.c — program text into the arena: a file read whole, or a string
 * given by the caller (NpgOptions.source). */
#include <errno.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>

#include "compile.h"

/* A program is text a person wrote; anything larger is not one, and the cap
 * bounds what a wrong path (/dev/zero) makes us read. */
#define SOURCE_MAX ((size_t)16 << 20)

SrcFile *source_from_string(Ctx *ctx, const char *name, const char *text, size_t len) {
  SrcFile *f = arena_alloc(ctx, sizeof *f);
  f->name = arena_strdup(ctx, name);
  f->text = arena_strndup(ctx, text, len);
  f->len = len;
  vec_push(ctx, &ctx->files, f);
  return f;
}

SrcFile *source_read(Ctx *ctx, const char *path) {
  struct stat st;
  if (stat(path, &st) == 0 && S_ISDIR(st.st_mode)) {
    errno = EISDIR;
    return NULL;
  }
  FILE *fp = fopen(path, "rb");
  if (!fp) return NULL;
  ctx->open_file = fp;  /* closed by npg_compile if an allocation fails below */
  size_t cap = 4096, len = 0;
  char *buf = arena_alloc(ctx, cap);
  for (;;) {
    if (len + 1 >= cap) {
      buf = arena_grow(ctx, buf, len, cap * 2);
      cap *= 2;
    }
    size_t got = fread(buf + len, 1, cap - 1 - len, fp);
    len += got;
    if (got == 0) break;
    if (len > SOURCE_MAX) {
      ctx->open_file = NULL;
      fclose(fp);
      errno = EFBIG;
      return NULL;
    }
  }
  int bad = ferror(fp);
  ctx->open_file = NULL;
  fclose(fp);
  if (bad) {
    errno = EIO;
    return NULL;
  }
  buf[len] = 0;  /* arena memory is zeroed; explicit for the reader */
  SrcFile *f = arena_alloc(ctx, sizeof *f);
  f->name = arena_strdup(ctx, path);
  f->text = buf;
  f->len = len;
  vec_push(ctx, &ctx->files, f);
  return f;
}
