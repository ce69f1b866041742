/* jit_cache.c — compiled evaluators kept on disk, keyed by content (jit_cache.h). */
#include "jit_cache.h"

#include <dirent.h>
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

/* ------------------------------------------------------------ SHA-256 (FIPS 180-4) */

typedef struct Sha256 {
  uint32_t h[8];
  uint8_t buf[64];
  uint64_t len;
} Sha256;

static const uint32_t K[64] = {
    0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5,
    0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174,
    0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa, 0x5cb0a9dc, 0x76f988da,
    0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967,
    0x27b70a85, 0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85,
    0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070,
    0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
    0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2};

#define ROR(x, n) (((x) >> (n)) | ((x) << (32 - (n))))

static void sha_block(Sha256 *s, const uint8_t *p) {
  uint32_t w[64];
  for (int i = 0; i < 16; i++) w[i] = (uint32_t)p[4 * i] << 24 | (uint32_t)p[4 * i + 1] << 16 | (uint32_t)p[4 * i + 2] << 8 | p[4 * i + 3];
  for (int i = 16; i < 64; i++) {
    uint32_t s0 = ROR(w[i - 15], 7) ^ ROR(w[i - 15], 18) ^ (w[i - 15] >> 3);
    uint32_t s1 = ROR(w[i - 2], 17) ^ ROR(w[i - 2], 19) ^ (w[i - 2] >> 10);
    w[i] = w[i - 16] + s0 + w[i - 7] + s1;
  }
  uint32_t a = s->h[0], b = s->h[1], c = s->h[2], d = s->h[3], e = s->h[4], f = s->h[5], g = s->h[6], h = s->h[7];
  for (int i = 0; i < 64; i++) {
    uint32_t t1 = h + (ROR(e, 6) ^ ROR(e, 11) ^ ROR(e, 25)) + ((e & f) ^ (~e & g)) + K[i] + w[i];
    uint32_t t2 = (ROR(a, 2) ^ ROR(a, 13) ^ ROR(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
    h = g, g = f, f = e, e = d + t1, d = c, c = b, b = a, a = t1 + t2;
  }
  s->h[0] += a, s->h[1] += b, s->h[2] += c, s->h[3] += d, s->h[4] += e, s->h[5] += f, s->h[6] += g, s->h[7] += h;
}

static void sha_init(Sha256 *s) {
  static const uint32_t h0[8] = {0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a,
                                 0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19};
  memcpy(s->h, h0, sizeof h0);
  s->len = 0;
}

static void sha_update(Sha256 *s, const void *data, size_t n) {
  const uint8_t *p = data;
  size_t have = (size_t)(s->len % 64);
  s->len += n;
  if (have) {
    size_t take = 64 - have < n ? 64 - have : n;
    memcpy(s->buf + have, p, take);
    p += take, n -= take, have += take;
    if (have < 64) return;
    sha_block(s, s->buf);
  }
  for (; n >= 64; p += 64, n -= 64) sha_block(s, p);
  memcpy(s->buf, p, n);
}

static void sha_hex(Sha256 *s, char hex[65]) {
  uint64_t bits = s->len * 8;
  uint8_t pad[72] = {0x80};
  size_t have = (size_t)(s->len % 64), npad = (have < 56 ? 56 : 120) - have;
  for (int i = 0; i < 8; i++) pad[npad + (size_t)i] = (uint8_t)(bits >> (56 - 8 * i));
  sha_update(s, pad, npad + 8);
  for (int i = 0; i < 8; i++) snprintf(hex + 8 * i, 9, "%08x", s->h[i]);
}

void jit_cache_sha256_hex(const void *data, size_t n, char hex[65]) {
  Sha256 s;
  sha_init(&s);
  sha_update(&s, data, n);
  sha_hex(&s, hex);
}

void jit_cache_key(const char *source, const char *cc_identity, const char *flags, char key[65]) {
  Sha256 s;
  sha_init(&s);
  /* each part with its length, so no two triples hash the same text */
  const char *parts[3] = {source, cc_identity, flags};
  for (int i = 0; i < 3; i++) {
    uint64_t n = strlen(parts[i]);
    sha_update(&s, &n, sizeof n);
    sha_update(&s, parts[i], n);
  }
  sha_hex(&s, key);
}

/* ------------------------------------------------------------ the folder */

/* "256M" and the like: bytes, or -1. */
static long long parse_size(const char *v) {
  char *end;
  errno = 0;
  long long n = strtoll(v, &end, 10);
  if (end == v || errno || n < 0) return -1;
  long long unit = 1;
  if (*end == 'K' || *end == 'k') unit = 1LL << 10, end++;
  else if (*end == 'M' || *end == 'm') unit = 1LL << 20, end++;
  else if (*end == 'G' || *end == 'g') unit = 1LL << 30, end++;
  if (*end || n > (1LL << 62) / unit) return -1;
  return n * unit;
}

/* mkdir -p of `path` (mode 0700 for what it creates): 0 or -1 with errno. */
static int make_dirs(char *path) {
  for (char *p = path + 1; *p; p++) {
    if (*p != '/') continue;
    *p = 0;
    int rc = mkdir(path, 0700);
    *p = '/';
    if (rc != 0 && errno != EEXIST) return -1;
  }
  if (mkdir(path, 0700) != 0 && errno != EEXIST) return -1;
  struct stat st;
  if (stat(path, &st) != 0) return -1;
  if (!S_ISDIR(st.st_mode)) {
    errno = ENOTDIR;
    return -1;
  }
  return access(path, W_OK | X_OK);
}

int jit_cache_open(JitCache *c, char *err, size_t errlen) {
  c->dir[0] = 0;
  c->max = 256LL << 20;
  const char *mx = getenv("NPG_CACHE_MAX");
  if (mx && *mx && (c->max = parse_size(mx)) < 0) {
    snprintf(err, errlen, "NPG_CACHE_MAX='%.60s' is not a size in bytes (a whole number, optionally followed by K, M or G; 0 turns the cache off)", mx);
    return -1;
  }
  if (c->max == 0) return 0;
  const char *env = getenv("NPG_CACHE_DIR");
  if (env && *env) {
    if (strlen(env) + 80 > sizeof c->dir) {
      snprintf(err, errlen, "NPG_CACHE_DIR (%.60s...) is %zu bytes long, more than the %zu the cache allows", env,
               strlen(env), sizeof c->dir - 80);
      return -1;
    }
    snprintf(c->dir, sizeof c->dir, "%s", env);
    if (make_dirs(c->dir) != 0) {
      int e = errno;
      c->dir[0] = 0;
      if (e == EACCES || e == EPERM || e == EROFS) return 0; /* another user's or a read-only folder: not cached */
      snprintf(err, errlen, "NPG_CACHE_DIR='%.200s' is not a folder npg can write: %s", env, strerror(e));
      return -1;
    }
    return 0;
  }
  const char *xdg = getenv("XDG_CACHE_HOME"), *home = getenv("HOME");
  int n;
  if (xdg && *xdg == '/') n = snprintf(c->dir, sizeof c->dir, "%s/npg", xdg);
  else if (home && *home == '/') n = snprintf(c->dir, sizeof c->dir, "%s/.cache/npg", home);
  else n = -1;
  if (n < 0 || (size_t)n + 80 > sizeof c->dir || make_dirs(c->dir) != 0) c->dir[0] = 0; /* no cache, no error */
  return 0;
}

/* ------------------------------------------------------------ entries */

#define MAGIC "NPGJITCACHE1"
#define TRAILER (sizeof MAGIC - 1 + 64 + 64) /* magic, key, sha256 of the object */

static void entry_path(const JitCache *c, const char *key, char *path, size_t n) {
  snprintf(path, n, "%s/%s.so", c->dir, key);
}

/* Whole file into memory (NULL on failure), when this user owns it: a shared
 * object someone else put in the folder is never loaded. */
static unsigned char *read_all(const char *path, size_t *n) {
  int fd = open(path, O_RDONLY | O_CLOEXEC);
  if (fd < 0) return NULL;
  struct stat st;
  unsigned char *buf = NULL;
  if (fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && st.st_uid == geteuid() && st.st_size > 0 &&
      (buf = malloc((size_t)st.st_size))) {
    size_t got = 0;
    while (got < (size_t)st.st_size) {
      ssize_t r = read(fd, buf + got, (size_t)st.st_size - got);
      if (r < 0 && errno == EINTR) continue;
      if (r <= 0) break;
      got += (size_t)r;
    }
    if (got != (size_t)st.st_size) free(buf), buf = NULL;
    *n = got;
  }
  close(fd);
  return buf;
}

/* The trailer names `key` and hashes the bytes before it. */
static bool trailer_ok(const unsigned char *buf, size_t n, const char *key) {
  if (n <= TRAILER) return false;
  const unsigned char *t = buf + n - TRAILER;
  if (memcmp(t, MAGIC, sizeof MAGIC - 1) != 0 || memcmp(t + sizeof MAGIC - 1, key, 64) != 0) return false;
  char hex[65];
  jit_cache_sha256_hex(buf, n - TRAILER, hex);
  return memcmp(t + sizeof MAGIC - 1 + 64, hex, 64) == 0;
}

void *jit_cache_load(const JitCache *c, const char *key, bool *damaged) {
  *damaged = false;
  if (!c->dir[0]) return NULL;
  char path[1200];
  entry_path(c, key, path, sizeof path);
  size_t n = 0;
  unsigned char *buf = read_all(path, &n);
  if (!buf) {
    if (access(path, F_OK) == 0) *damaged = true, unlink(path); /* empty or unreadable */
    return NULL;
  }
  bool ok = trailer_ok(buf, n, key);
  free(buf);
  void *dl = ok ? dlopen(path, RTLD_NOW | RTLD_LOCAL) : NULL;
  if (ok && !dl && access(path, F_OK) != 0) return NULL; /* evicted by another process meanwhile: a miss */
  if (!dl) {
    *damaged = true;
    unlink(path);
    return NULL;
  }
  utimensat(AT_FDCWD, path, NULL, 0); /* recently used: evicted last */
  return dl;
}

int jit_cache_seal(const char *tmp_so, const char *key, char *err, size_t errlen) {
  size_t n = 0;
  unsigned char *buf = read_all(tmp_so, &n);
  if (!buf) {
    snprintf(err, errlen, "cannot read %s: %s", tmp_so, strerror(errno));
    return -1;
  }
  char t[TRAILER + 1];
  char hex[65];
  jit_cache_sha256_hex(buf, n, hex);
  free(buf);
  snprintf(t, sizeof t, "%s%s%s", MAGIC, key, hex);
  FILE *f = fopen(tmp_so, "ab");
  if (!f || fwrite(t, 1, TRAILER, f) != TRAILER || fclose(f) != 0) {
    snprintf(err, errlen, "cannot write %s: %s", tmp_so, strerror(errno));
    return -1;
  }
  return 0;
}

typedef struct Entry {
  char name[80];
  long long size;
  struct timespec mtime;
} Entry;

static int by_age(const void *a, const void *b) {
  const Entry *x = a, *y = b;
  if (x->mtime.tv_sec != y->mtime.tv_sec) return x->mtime.tv_sec < y->mtime.tv_sec ? -1 : 1;
  return (x->mtime.tv_nsec > y->mtime.tv_nsec) - (x->mtime.tv_nsec < y->mtime.tv_nsec);
}

/* An entry's name: 64 hex digits and ".so"; a temporary one: that, ".tmp.", more. */
static int entry_kind(const char *name) {
  size_t i = 0;
  while (i < 64 && ((name[i] >= '0' && name[i] <= '9') || (name[i] >= 'a' && name[i] <= 'f'))) i++;
  if (i != 64 || strncmp(name + 64, ".so", 3) != 0) return 0;
  if (!name[67]) return 1;
  return strncmp(name + 67, ".tmp.", 5) == 0 ? 2 : 0;
}

/* Remove the oldest entries until the folder holds at most c->max bytes;
 * temporary files a crashed process left over an hour ago go too. Files
 * that are not the cache's are never touched. */
static void evict(const JitCache *c, const char *keep) {
  DIR *d = opendir(c->dir);
  if (!d) return;
  Entry *e = NULL;
  size_t n = 0, cap = 0;
  long long total = 0;
  time_t now = time(NULL);
  char path[1200];
  for (struct dirent *de; (de = readdir(d));) {
    int kind = entry_kind(de->d_name);
    if (!kind || strlen(de->d_name) >= sizeof e->name) continue;
    snprintf(path, sizeof path, "%s/%s", c->dir, de->d_name);
    struct stat st;
    if (stat(path, &st) != 0) continue;
    if (kind == 2) {
      if (now - st.st_mtime > 3600) unlink(path);
      continue;
    }
    if (strncmp(de->d_name, keep, 64) == 0) {
      total += st.st_size;
      continue;
    }
    if (n == cap) {
      Entry *g = realloc(e, (cap = cap ? 2 * cap : 64) * sizeof *e);
      if (!g) break;
      e = g;
    }
    snprintf(e[n].name, sizeof e[n].name, "%s", de->d_name);
    e[n].size = st.st_size;
    e[n].mtime = st.st_mtim;
    total += st.st_size;
    n++;
  }
  closedir(d);
  if (n) qsort(e, n, sizeof *e, by_age);
  for (size_t i = 0; i < n && total > c->max; i++) {
    snprintf(path, sizeof path, "%s/%s", c->dir, e[i].name);
    if (unlink(path) == 0) total -= e[i].size;
  }
  free(e);
}

int jit_cache_store(const JitCache *c, const char *tmp_so, const char *key, char *err, size_t errlen) {
  char path[1200];
  entry_path(c, key, path, sizeof path);
  if (rename(tmp_so, path) != 0) {
    snprintf(err, errlen, "cannot rename %s to %s: %s", tmp_so, path, strerror(errno));
    unlink(tmp_so);
    return -1;
  }
  evict(c, key);
  return 0;
}
