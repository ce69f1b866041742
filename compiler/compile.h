/* compile.h — the compiler's stages, called in order by npg_compile(). */
#ifndef NPG_COMPILE_H
#define NPG_COMPILE_H

#include "ir.h"

bool is_keyword(const char *s);
/* compiler/parse.c: tokens to declarations; reads `use`d modules. */
Decl *parse_program(Ctx *ctx, const SrcFile *file);
/* compiler/sema.c: names, fn inlining, types, every rule of DESIGN §3. */
Program *sema_program(Ctx *ctx, const SrcFile *file, Decl *decls);
/* compiler/dumpast.c: -dp, the parsed declarations. */
void dump_decls(FILE *out, const Decl *d);
void dump_checked(FILE *out, const Program *prog);
/* compiler/eval.c: the `npgc eval` command. */
int npgc_eval(int argc, char **argv);
/* compiler/reduce_cmds.c: train, reduced eval, verify, bench. */
int npgc_reduce(int argc, char **argv);
/* npgc plot MODEL/ -o spectra.png (plot.c, linked into npgc only) */
int npgc_plot(int argc, char **argv);
/* npgc tune PROG.npg DATA/ VALID/ --tol T -o MODEL/ (tune.c, linked into npgc only) */
int npgc_tune(int argc, char **argv);
/* compiler/npg.c: the stage program of a compiled NpgProgram (tests, backends). */
struct NpgProgram;
Program *npg_program_ir(const struct NpgProgram *p);

#endif
