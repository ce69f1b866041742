/* words.c — the one table of how each interface spells a training option (issue 38).
 *
 * Training writes its messages in npgc's words ("--basis nosuch: no quantity ...", "raise --mem");
 * a trainer made from npg.h or Python hands them back in its caller's words (NpgTrainOptions.words),
 * so a C program reads the field it set ("NpgTrainOptions.basis_name nosuch: ...") and a Python
 * one the keyword it passed ("basis nosuch: ..."). One row per option: adding an option to npgc
 * train, NpgTrainOptions and npg.Trainer adds its row here. */
#include <stdio.h>
#include <string.h>

#include "api.h"

static const struct {
  const char *word[3]; /* NPG_WORDS_C, NPG_WORDS_NPGC, NPG_WORDS_PYTHON */
} option_words[] = {
  /* the longer spellings first: "--merge joint" before "--merge" */
  {{"NpgTrainOptions.keep_bases", "--keep-bases", "keep_bases"}},
  {{"NpgTrainOptions.basis_name", "--basis", "basis"}},
  {{"NpgTrainOptions.mem", "--mem", "mem"}},
  {{"NpgTrainOptions.cap", "--cap", "cap"}},
  {{"NpgTrainOptions.energy", "--energy", "energy"}},
  {{"NpgTrainOptions.uncentered", "--center", "center"}},
  {{"NpgTrainOptions.joint = true", "--merge joint", "joint=True"}},
  {{"NpgTrainOptions.joint", "--merge", "joint"}},
  {{"NpgTrainOptions.interp_oversample", "--interp-oversample", "interp_oversample"}},
  {{"NpgTrainOptions.valid_holdout", "--valid", "valid_holdout"}},
  {{"NpgTrainOptions.progress", "--progress", "progress"}},
  {{"npg_full_set_extern_fn", "npg_full_set_extern_fn", "full.extern"}},
  {{"npg_trainer_weight", "npg_trainer_weight", "Trainer.weight"}},
  {{"npg_trainer_dots", "npg_trainer_dots", "Trainer.dots"}},
};

/* "--reduce NAME:interp" (or :galerkin) in `words`: "NpgTrainOptions.interp_stage NAME", "interp NAME".
 * The characters of `msg` it stands for, 0 when `msg` does not start with one. */
static size_t reduce_words(const char *msg, int words, char *out, size_t len, size_t *o) {
  if (strncmp(msg, "--reduce ", 9) != 0) return 0;
  const char *name = msg + 9, *colon = strchr(name, ':');
  const char *kind = colon && strncmp(colon + 1, "interp", 6) == 0     ? "interp"
                     : colon && strncmp(colon + 1, "galerkin", 8) == 0 ? "galerkin"
                                                                       : NULL;
  if (!kind || colon - name > 256) return 0;
  int n = words == NPG_WORDS_PYTHON ? snprintf(out + *o, len - *o, "%s %.*s", kind, (int)(colon - name), name)
                                    : snprintf(out + *o, len - *o, "NpgTrainOptions.%s_stage %.*s", kind,
                                               (int)(colon - name), name);
  *o = n > 0 && *o + (size_t)n < len ? *o + (size_t)n : len - 1;
  return (size_t)(colon + 1 - msg) + strlen(kind);
}

void api_words(const char *msg, int words, char *out, size_t len) {
  if (!len) return;
  if (words == NPG_WORDS_NPGC || (words != NPG_WORDS_C && words != NPG_WORDS_PYTHON)) {
    snprintf(out, len, "%s", msg);
    return;
  }
  size_t o = 0;
  for (size_t i = 0; msg[i] && o + 1 < len;) {
    size_t used = reduce_words(msg + i, words, out, len, &o);
    for (size_t k = 0; !used && k < sizeof option_words / sizeof *option_words; k++) {
      const char *from = option_words[k].word[NPG_WORDS_NPGC];
      size_t n = strlen(from);
      char after = msg[i + n];
      /* a whole word: "--mem", not the start of "--memory" */
      if (strncmp(msg + i, from, n) == 0 && (!after || strchr(" :,)=;'", after))) {
        int w = snprintf(out + o, len - o, "%s", option_words[k].word[words]);
        o = w > 0 && o + (size_t)w < len ? o + (size_t)w : len - 1;
        used = n;
      }
    }
    if (!used) out[o++] = msg[i++];
    else i += used;
  }
  out[o] = 0;
}
