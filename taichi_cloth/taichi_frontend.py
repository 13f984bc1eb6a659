"""Taichi's Python front end without two costs that bring nothing: most of a kernel's Python-side compile time.

While Taichi 1.7 turns a kernel's Python into its IR (every compile, and every run that loads kernels from the
offline cache, whose keys come from that IR) it
  * formats, for every statement and expression it visits, the message a compile error would show there (file,
    line, the code, a caret line under it) and wraps each line at 80 columns with `textwrap`. Nearly all of that
    text is never read; the wrapping is most of its cost;
  * reads and tokenises a function's source file again each time the function is inlined (`inspect.getsourcelines`
    for every call site of every `ti.func`).
Profiled on a cold compile of the implicit step with self-collision (docs/performance.md, the test suite), the two
took 8.9 s and 2.1 s of 18.4 s of AST transformation. `install` replaces the formatting with one that gives the same
message without the wrapping (a code line longer than 80 columns stays one line: errors still point at the code),
and reads each function's source once per process (the AST is still parsed for every inlining: the transformer
writes into it). It applies only to the Taichi versions this was read on (1.7); elsewhere Taichi is left as it
is, and so it is with TAICHI_CLOTH_TAICHI_FRONTEND=plain (to measure the difference).
"""
from __future__ import annotations

import ast
import os
import textwrap

import taichi as ti
import taichi.lang._wrap_inspect as wrap_inspect
from taichi.lang import kernel_impl
from taichi.lang.ast import ast_transformer_utils

#: the Taichi versions whose ASTTransformerContext.get_pos_info this replaces (read on 1.7.4)
VERSIONS = ((1, 7),)

_installed = False
#: Taichi's own ASTTransformerContext.get_pos_info, kept by install (the tests compare the two)
_ORIGINAL_GET_POS_INFO = None


def _span(src: list[str], i: int) -> tuple[int, int]:
    """(first, last): the columns of line i's first and one past its last printable non-space character."""
    line = src[i]
    last = len(line)
    while last > 0 and (line[last - 1].isspace() or not line[last - 1].isprintable()):
        last -= 1
    first = 0
    while first < len(line) and (line[first].isspace() or not line[first].isprintable()):
        first += 1
    return first, last


def get_pos_info(self, node) -> str:
    """Taichi's message for `node` (ASTTransformerContext.get_pos_info): the file, line and function, then each
    source line of the node with a caret line under the node's span; not wrapped."""
    msg = f'File "{self.file}", line {node.lineno + self.lineno_offset}, in {self.func.func.__name__}:\n'
    col_offset = self.indent + node.col_offset
    end_col_offset = self.indent + node.end_col_offset
    src = self.src
    if node.lineno == node.end_lineno:
        code = src[node.lineno - 1]
        return msg + (code + "\n" + " " * col_offset + "^" * (end_col_offset - col_offset) + "\n" if code else "\n\n")
    if node.__class__.__name__ in ("For", "While", "FunctionDef", "If"):
        end_lineno = max(node.body[0].lineno - 1, node.lineno)
    else:
        end_lineno = node.end_lineno
    parts = [msg]
    for i in range(node.lineno - 1, end_lineno):
        first, last = _span(src, i)
        if i == node.lineno - 1:
            hint = " " * col_offset + "^" * (last - col_offset)
        elif i == node.end_lineno - 1:
            hint = " " * first + "^" * (end_col_offset - first)
        elif first < last:
            hint = " " * first + "^" * (last - first)
        else:
            hint = ""
        parts.append(src[i] + "\n" + hint + "\n" if src[i] else "\n\n")
    return "".join(parts)


#: a function's (file, source lines as Taichi prepares them, first line number, dedented source), by code object
_sources: dict = {}


def _source(func):
    """(file, src, start_lineno, text) of a Python function, read once: Taichi's own preparation (its tabs expanded
    by textwrap.fill, the lines joined and dedented)."""
    key = getattr(func, "__code__", func)  # functions made by one factory share their code and their source
    found = _sources.get(key)
    if found is None:
        src, start_lineno = wrap_inspect.getsourcelines(func)
        src = [textwrap.fill(line, tabsize=4, width=9999) for line in src]
        found = _sources[key] = (wrap_inspect.getsourcefile(func), src, start_lineno, textwrap.dedent("\n".join(src)))
    return found


def get_tree_and_ctx(self, excluded_parameters=(), is_kernel=True, arg_features=None, args=None, ast_builder=None,
                     is_real_function=False):
    """Taichi 1.7's kernel_impl._get_tree_and_ctx with the function's source read once (_source)."""
    file, src, start_lineno, text = _source(self.func)
    tree = ast.parse(text)
    tree.body[0].decorator_list = []
    global_vars = kernel_impl._get_global_vars(self.func)
    if is_kernel or is_real_function:
        for i in self.template_slot_locations:  # template parameters are globals of the kernel's body
            global_vars[self.arguments[i].name] = args[i]
    context = ast_transformer_utils.ASTTransformerContext
    return tree, context(excluded_parameters=excluded_parameters, is_kernel=is_kernel, func=self,
                         arg_features=arg_features, global_vars=global_vars, argument_data=args, src=src,
                         start_lineno=start_lineno, file=file, ast_builder=ast_builder,
                         is_real_function=is_real_function)


def install() -> bool:
    """Use get_pos_info and get_tree_and_ctx in Taichi's front end (once); False where this Taichi is not a version
    they were read on, or does not have what they replace (then nothing is replaced)."""
    global _installed, _ORIGINAL_GET_POS_INFO
    if _installed:
        return True
    if tuple(ti.__version__[:2]) not in VERSIONS or os.environ.get("TAICHI_CLOTH_TAICHI_FRONTEND") == "plain":
        return False
    context = getattr(ast_transformer_utils, "ASTTransformerContext", None)
    if (context is None or not hasattr(context, "get_pos_info") or not hasattr(kernel_impl, "_get_tree_and_ctx")
            or not hasattr(kernel_impl, "_get_global_vars")):
        return False
    _ORIGINAL_GET_POS_INFO = context.get_pos_info
    context.get_pos_info = get_pos_info
    kernel_impl._get_tree_and_ctx = get_tree_and_ctx
    _installed = True
    return True
