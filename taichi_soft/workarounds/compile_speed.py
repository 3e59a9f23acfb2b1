"""Faster kernel compiles on Taichi 1.7.4: two costs of its Python front end that buy nothing here.

Every ``Simulation`` compiles its own kernels (they read its fields), and on a 2-core VM the
front end that turns a kernel's Python into Taichi IR is a large part of that:

- for every AST node Taichi renders a caret-underlined excerpt of the source line through
  ``textwrap`` (``ASTTransformerContext.get_pos_info``) and attaches it as debug info, which only
  a compile error would print: about 45 000 renderings for one fast_mass_spring step;
- for every call of a ``ti.func`` it reads, re-tokenises and re-wraps the function's source file
  lines (``kernel_impl._get_tree_and_ctx``): 869 times for the same step.

- for every field and SNode it allocates it formats the whole Python stack
  (``util.get_traceback``: every frame, each source line read back through ``linecache``) into a
  "declared here" note that only an error about an unplaced field prints: about 1300 stacks of
  40-80 frames for the three solvers of a small test, 1.0 of its 11 s with warm kernels.

``install()`` keeps the file, line and function of every node's debug info (a compile error still
says where) without the excerpt, reads each function's source once per process (a fresh
``ast.parse`` each call, as Taichi does, since the transformer writes into the tree), and keeps
the innermost ``DECLARATION_FRAMES`` frames of a declaration's stack. The IR and hence the
compiled kernels are unchanged: the offline cache hits across patched and unpatched runs, and
``scripts/same_answers.py`` gives bit-identical final states.

It takes about a quarter off a compile (docs/decisions/compile-front-end.md).

Only on the Taichi version it was written against: any other version runs Taichi's own code.
"""
from __future__ import annotations

import ast
import sys
import textwrap
import traceback
import weakref

import taichi as ti

VERSION = (1, 7, 4)
# Frames of the Python stack kept in a field's or SNode's "declared here" note: the caller's own
# code and a few frames above it, not the test runner or command line below.
DECLARATION_FRAMES = 8

_installed = False


def install() -> bool:
    """Patch Taichi's front end (idempotent); returns whether it is in place (False on another
    Taichi version or if the functions it replaces are not where 1.7.4 has them)."""
    global _installed
    if _installed:
        return True
    if tuple(ti.__version__) != VERSION:
        return False
    from taichi.lang import impl, kernel_impl, snode
    from taichi.lang.ast import ast_transformer_utils

    context = getattr(ast_transformer_utils, "ASTTransformerContext", None)
    if (context is None or not hasattr(context, "get_pos_info") or not hasattr(kernel_impl, "_get_tree_and_ctx")
            or not hasattr(impl, "get_traceback") or not hasattr(snode, "get_traceback")):
        return False
    context.get_pos_info = _pos_info
    kernel_impl._get_tree_and_ctx = _tree_and_ctx
    impl.get_traceback = snode.get_traceback = _declaration_traceback
    _installed = True
    return True


def _declaration_traceback(stacklevel=1) -> str:
    """Taichi's ``util.get_traceback`` limited to the innermost ``DECLARATION_FRAMES`` frames: the
    same frames end the note (the caller ``stacklevel`` frames up and those it was called from)."""
    return "".join(traceback.format_list(traceback.extract_stack(sys._getframe(1 + stacklevel),
                                                                 limit=DECLARATION_FRAMES)))


def _pos_info(ctx, node) -> str:
    """Taichi's debug info of a node without the source excerpt: file, line, function."""
    return f'File "{ctx.file}", line {node.lineno + ctx.lineno_offset}, in {ctx.func.func.__name__}:\n'


# function -> (file, source lines as Taichi prepares them, first line number, dedented source); weak,
# so a kernel defined inside a function (a closure over its fields) is not kept alive by the cache
_sources: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _source(func):
    found = _sources.get(func)
    if found is None:
        from taichi.lang import kernel_impl

        lines, start = kernel_impl.getsourcelines(func)
        lines = [textwrap.fill(line, tabsize=4, width=9999) for line in lines]
        found = _sources[func] = (kernel_impl.getsourcefile(func), lines, start, textwrap.dedent("\n".join(lines)))
    return found


def _tree_and_ctx(self, excluded_parameters=(), is_kernel=True, arg_features=None, args=None, ast_builder=None,
                  is_real_function=False):
    """``kernel_impl._get_tree_and_ctx`` of Taichi 1.7.4 with the source read once per function."""
    from taichi.lang import kernel_impl
    from taichi.lang.ast.ast_transformer_utils import ASTTransformerContext

    file, lines, start_lineno, text = _source(self.func)
    tree = ast.parse(text)
    tree.body[0].decorator_list = []
    global_vars = kernel_impl._get_global_vars(self.func)
    if is_kernel or is_real_function:
        # Template parameters are injected into the globals, as Taichi does.
        for i in self.template_slot_locations:
            global_vars[self.arguments[i].name] = args[i]
    return tree, ASTTransformerContext(excluded_parameters=excluded_parameters, is_kernel=is_kernel, func=self,
                                       arg_features=arg_features, global_vars=global_vars, argument_data=args,
                                       src=lines, start_lineno=start_lineno, file=file, ast_builder=ast_builder,
                                       is_real_function=is_real_function)
