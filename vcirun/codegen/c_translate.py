"""The statement-for-statement translation of one generated numba kernel to C (vcirun.codegen.c_emit
decides which kernels and binds them). The subset: straight-line arithmetic on float64 scalars and
the elements of 1-D / 2-D arrays of compile-time shape, math functions, for loops over constant
ranges; operators keep numba's order (no reassociation), so the C code computes the same numbers.
Anything outside it raises Unsupported: that kernel stays in numba.
"""
from __future__ import annotations

import ast
import re
from dataclasses import dataclass, field

from .cc import SEGMENT_LINES

_MATH1 = {"sin": "sin", "cos": "cos", "tan": "tan", "asin": "asin", "acos": "acos", "atan": "atan",
          "sinh": "sinh", "cosh": "cosh", "tanh": "tanh", "asinh": "asinh", "acosh": "acosh", "atanh": "atanh",
          "exp": "exp", "expm1": "expm1", "log": "log", "log1p": "log1p", "log10": "log10", "log2": "log2",
          "sqrt": "sqrt", "fabs": "fabs", "floor": "floor", "ceil": "ceil", "erf": "erf", "erfc": "erfc",
          "gamma": "tgamma", "lgamma": "lgamma", "trunc": "trunc"}
_MATH2 = {"pow": "pow", "atan2": "atan2", "hypot": "hypot", "fmod": "fmod", "copysign": "copysign"}
_CONSTS = {("math", "pi"): "M_PI", ("np", "pi"): "M_PI", ("math", "e"): "M_E", ("np", "e"): "M_E",
           ("math", "inf"): "INFINITY", ("np", "inf"): "INFINITY", ("math", "nan"): "NAN", ("np", "nan"): "NAN"}
_BIN = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/"}
_CMP = {ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">=", ast.Eq: "==", ast.NotEq: "!="}
_HEAP = 4096  # local arrays above this many doubles live on the heap (thread stacks of workers are small)
class Unsupported(Exception):
    """The kernel uses something outside the translated subset (it stays in numba)."""


@dataclass
class CKernel:
    name: str
    args: list            # [(name, kind)] kind: "s" scalar, "1" 1-D array, "2" 2-D array, "-" unused
    returns: str          # "double" or "int64"
    c_body: str           # the C function (symbol name __NAME__)
    docstring: str = ""
    statements: int = 0
    stores_2d: int = 0    # assignments to a 2-D array element (numba types and lowers each at a cost)

    @property
    def weight(self) -> int:
        """What decides C or numba: statements plus 2-D element stores (n = 8's sys_node_M, 64 stores
        and nothing else, cost numba 1.2-1.5 s)."""
        return self.statements + self.stores_2d


@dataclass
class _Fn:
    args: dict
    arrays: dict = field(default_factory=dict)     # local array -> (rows, cols or None)
    scalars: dict = field(default_factory=dict)    # local scalar -> None (ordered)
    loopvars: dict = field(default_factory=dict)
    heap: list = field(default_factory=list)


def int_const(node, consts: dict, args=()) -> int:
    """A compile-time integer: a literal, a module constant such as NDOF, or +, -, * of those."""
    if isinstance(node, ast.Constant) and isinstance(node.value, int) and not isinstance(node.value, bool):
        return node.value
    if isinstance(node, ast.Name) and node.id in consts and node.id not in args:
        return consts[node.id]
    if isinstance(node, ast.BinOp) and type(node.op) in (ast.Add, ast.Sub, ast.Mult):
        a, b = int_const(node.left, consts, args), int_const(node.right, consts, args)
        return a + b if isinstance(node.op, ast.Add) else a - b if isinstance(node.op, ast.Sub) else a * b
    raise Unsupported("a shape that is not a compile-time integer")


def _arg_kinds(fn: ast.FunctionDef) -> dict:
    """Each argument's kind: "1"/"2" indexed with one/two indices, "s" used as a value, "-" unused
    (the C function does not take it)."""
    kinds = {a.arg: "-" for a in fn.args.args}
    for node in ast.walk(fn):
        if isinstance(node, ast.Name) and node.id in kinds and kinds[node.id] == "-":
            kinds[node.id] = "s"
    for node in ast.walk(fn):
        if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name) and node.value.id in kinds:
            k = "2" if isinstance(node.slice, ast.Tuple) else "1"
            if isinstance(node.slice, ast.Tuple) and len(node.slice.elts) != 2:
                raise Unsupported("an index of more than two dimensions")
            old = kinds[node.value.id]
            if old in ("1", "2") and old != k:
                raise Unsupported(f"argument {node.value.id} indexed with 1 and 2 indices")
            kinds[node.value.id] = k
    return kinds


class Translator:
    def __init__(self, fn: ast.FunctionDef, constants: dict):
        if fn.args.vararg or fn.args.kwarg or fn.args.kwonlyargs or fn.args.defaults or fn.args.posonlyargs:
            raise Unsupported("default, keyword or variadic arguments")
        self.fn = fn
        self.consts = constants
        self.f = _Fn(_arg_kinds(fn))
        self.ret_kinds = set()

    # -- names ----------------------------------------------------------------------------------
    @staticmethod
    def cid(name: str) -> str:
        return "p_" + name  # no clash with C keywords or libm names (y0, j1, gamma, ...)

    def int_const(self, node) -> int:
        return int_const(node, self.consts, self.f.args)

    # -- expressions ------------------------------------------------------------------------------
    def expr(self, node, index=False) -> str:
        t = type(node)
        if t is ast.Constant:
            v = node.value
            if isinstance(v, bool):
                return "1" if v else "0"
            if isinstance(v, int):
                return str(v) if index else f"{v}.0"
            if isinstance(v, float):
                if v != v:
                    return "NAN"
                if v in (float("inf"), float("-inf")):
                    return "INFINITY" if v > 0 else "(-INFINITY)"
                r = repr(v)
                return r if ("e" in r or "." in r) else r + ".0"
            raise Unsupported(f"constant {v!r}")
        if t is ast.Name:
            n = node.id
            if n in self.f.args or n in self.f.scalars or n in self.f.loopvars:
                if n in self.f.args and self.f.args[n] != "s":
                    raise Unsupported(f"array argument {n} used as a value")
                return self.cid(n)
            if n in self.consts and isinstance(self.consts[n], int):
                return str(self.consts[n]) if index else f"{self.consts[n]}.0"
            raise Unsupported(f"name {n} (a module global or undefined)")
        if t is ast.Attribute:
            if isinstance(node.value, ast.Name) and (node.value.id, node.attr) in _CONSTS:
                return _CONSTS[node.value.id, node.attr]
            raise Unsupported("attribute access")
        if t is ast.BinOp:
            if type(node.op) not in _BIN:
                if isinstance(node.op, ast.Pow) and not index:
                    return f"pow({self.expr(node.left)}, {self.expr(node.right)})"
                raise Unsupported(f"operator {type(node.op).__name__}")
            a, b = self.expr(node.left, index), self.expr(node.right, index)
            if isinstance(node.op, ast.Div):
                if index:
                    raise Unsupported("division in an index")
                return f"((double)({a}) / ({b}))"
            return f"({a} {_BIN[type(node.op)]} {b})"
        if t is ast.UnaryOp:
            if isinstance(node.op, ast.USub):
                return f"(-{self.expr(node.operand, index)})"
            if isinstance(node.op, ast.UAdd):
                return self.expr(node.operand, index)
            if isinstance(node.op, ast.Not):
                return f"(!{self.expr(node.operand, index)})"
            raise Unsupported("unary operator")
        if t is ast.IfExp:
            return f"(({self.expr(node.test)}) ? ({self.expr(node.body, index)}) : ({self.expr(node.orelse, index)}))"
        if t is ast.Compare:
            if len(node.ops) != 1 or type(node.ops[0]) not in _CMP:
                raise Unsupported("chained or non-arithmetic comparison")
            return f"({self.expr(node.left)} {_CMP[type(node.ops[0])]} {self.expr(node.comparators[0])})"
        if t is ast.BoolOp:
            op = " && " if isinstance(node.op, ast.And) else " || "
            return "(" + op.join(self.expr(v) for v in node.values) + ")"
        if t is ast.Subscript:
            return self.element(node)
        if t is ast.Call:
            return self.call(node, index)
        raise Unsupported(f"expression {t.__name__}")

    def call(self, node, index):
        if node.keywords:
            raise Unsupported("keyword arguments")
        f = node.func
        args = node.args
        if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) and f.value.id == "math":
            if f.attr in _MATH1 and len(args) == 1:
                return f"{_MATH1[f.attr]}({self.expr(args[0])})"
            if f.attr in _MATH2 and len(args) == 2:
                return f"{_MATH2[f.attr]}({self.expr(args[0])}, {self.expr(args[1])})"
            if f.attr == "isfinite" and len(args) == 1:
                return f"((double)isfinite({self.expr(args[0])}))"
            raise Unsupported(f"math.{f.attr}")
        if isinstance(f, ast.Name) and f.id == "abs" and len(args) == 1:
            return f"fabs({self.expr(args[0])})"
        if isinstance(f, ast.Name) and f.id in ("min", "max") and len(args) == 2:
            # Python's order of evaluation and choice (the first argument unless the second is
            # strictly smaller/larger), not fmin/fmax, which differ at NaN
            return f"_vk_{f.id}({self.expr(args[0])}, {self.expr(args[1])})"
        raise Unsupported("a call that is not a math function")

    def element(self, node) -> str:
        if not isinstance(node.value, ast.Name):
            raise Unsupported("indexing an expression")
        a = node.value.id
        if a in self.f.args:
            kind = self.f.args[a]
            rowlen = "r_" + self.cid(a)
        elif a in self.f.arrays:
            rows, cols = self.f.arrays[a]
            kind = "1" if cols is None else "2"
            rowlen = str(cols)
        else:
            raise Unsupported(f"indexing {a}")
        idx = node.slice
        if kind == "2":
            if not isinstance(idx, ast.Tuple):
                raise Unsupported(f"2-D array {a} indexed with one index")
            i, j = (self._index(e) for e in idx.elts)
            return f"{self.cid(a)}[({i}) * {rowlen} + ({j})]"
        if isinstance(idx, ast.Tuple):
            raise Unsupported(f"1-D array {a} indexed with two indices")
        return f"{self.cid(a)}[{self._index(idx)}]"

    def _index(self, node) -> str:
        if isinstance(node, ast.Slice):
            raise Unsupported("slice")
        try:
            v = self.int_const(node)
            if v < 0:
                raise Unsupported("negative index")
            return str(v)
        except Unsupported as e:
            if "negative" in str(e):
                raise
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            raise Unsupported("negative index")
        self._check_int(node)
        return self.expr(node, index=True)

    def _check_int(self, node):
        """Indices are built of loop variables, integer literals and module constants only."""
        for sub in ast.walk(node):
            if isinstance(sub, ast.Name) and not (sub.id in self.f.loopvars or
                                                  (sub.id in self.consts and sub.id not in self.f.args)):
                raise Unsupported(f"index from a non-integer name {sub.id}")
            if isinstance(sub, ast.Constant) and not isinstance(sub.value, int):
                raise Unsupported("non-integer index")
            if isinstance(sub, (ast.Call, ast.Subscript, ast.Attribute, ast.IfExp)):
                raise Unsupported("computed index")

    # -- statements -------------------------------------------------------------------------------
    def local_array(self, name, call) -> None:
        f = call.func
        if not (isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) and f.value.id == "np"
                and f.attr in ("empty", "zeros") and len(call.args) == 1 and not call.keywords):
            raise Unsupported("a call outside an expression")
        shp = call.args[0]
        if isinstance(shp, ast.Tuple):
            if len(shp.elts) == 1:
                rows, cols = self.int_const(shp.elts[0]), None
            elif len(shp.elts) == 2:
                rows, cols = self.int_const(shp.elts[0]), self.int_const(shp.elts[1])
            else:
                raise Unsupported("array of more than two dimensions")
        else:
            rows, cols = self.int_const(shp), None
        if name in self.f.arrays or name in self.f.scalars or name in self.f.args:
            raise Unsupported(f"{name} rebound")
        self.f.arrays[name] = (rows, cols)
        size = max(1, rows * (cols or 1))
        cname = self.cid(name)
        out = []
        if size > _HEAP:
            self.f.heap.append(cname)
            out.append(f"double *{cname} = (double *)malloc(sizeof(double) * {size});")
            out.append(f"if (!{cname}) abort();")
            if f.attr == "zeros":
                out.append(f"memset({cname}, 0, sizeof(double) * {size});")
        else:
            out.append(f"double {cname}[{size}]" + (" = {0};" if f.attr == "zeros" else ";"))
        return out

    def stmts(self, body, depth) -> list:
        out = []
        for st in body:
            out += self.stmt(st, depth)
        return out

    def stmt(self, st, depth) -> list:
        ind = "    " * depth
        t = type(st)
        if t is ast.Expr and isinstance(st.value, ast.Constant) and isinstance(st.value.value, str):
            return []
        if t is ast.Pass:
            return []
        if t is ast.Assign:
            if len(st.targets) != 1:
                raise Unsupported("chained assignment")
            tg = st.targets[0]
            if isinstance(tg, ast.Name):
                n = tg.id
                if isinstance(st.value, ast.Call) and isinstance(st.value.func, ast.Attribute) \
                        and isinstance(st.value.func.value, ast.Name) and st.value.func.value.id == "np":
                    if depth != 1:
                        raise Unsupported("a local array inside a block")
                    return [ind + ln for ln in self.local_array(n, st.value)]
                if n in self.f.args or n in self.f.arrays or n in self.f.loopvars:
                    raise Unsupported(f"assignment to {n}")
                val = self.expr(st.value)
                self.f.scalars.setdefault(n, None)
                return [f"{ind}{self.cid(n)} = {val};"]
            if isinstance(tg, ast.Subscript):
                return [f"{ind}{self.element(tg)} = {self.expr(st.value)};"]
            raise Unsupported("tuple assignment")
        if t is ast.AugAssign:
            if type(st.op) not in _BIN:
                raise Unsupported("augmented operator")
            tg = st.target
            if isinstance(tg, ast.Name):
                if tg.id not in self.f.scalars:
                    raise Unsupported(f"augmented assignment to {tg.id}")
                lhs = self.cid(tg.id)
            elif isinstance(tg, ast.Subscript):
                lhs = self.element(tg)
            else:
                raise Unsupported("augmented assignment target")
            rhs = self.expr(st.value)
            if isinstance(st.op, ast.Div):
                rhs = f"(double)({rhs})"
            return [f"{ind}{lhs} {_BIN[type(st.op)]}= {rhs};"]
        if t is ast.For:
            if st.orelse or not isinstance(st.target, ast.Name):
                raise Unsupported("for-else or tuple loop target")
            it = st.iter
            if not (isinstance(it, ast.Call) and isinstance(it.func, ast.Name) and it.func.id == "range"
                    and 1 <= len(it.args) <= 3 and not it.keywords):
                raise Unsupported("a loop over anything but range")
            v = st.target.id
            if v in self.f.scalars or v in self.f.args or v in self.f.arrays:
                raise Unsupported(f"loop variable {v} is also a value")
            a = [self._loop_bound(x) for x in it.args]
            lo, hi, step = ("0", a[0], 1) if len(a) == 1 else (a[0], a[1], 1) if len(a) == 2 else (a[0], a[1], None)
            if step is None:
                step = self.int_const(it.args[2])
                if step <= 0:
                    raise Unsupported("a loop with a non-positive step")
            self.f.loopvars.setdefault(v, None)
            cv = self.cid(v)
            head = f"{ind}for ({cv} = {lo}; {cv} < {hi}; {cv} += {step}) {{"
            return [head] + self.stmts(st.body, depth + 1) + [ind + "}"]
        if t is ast.If:
            out = [f"{ind}if ({self.expr(st.test)}) {{"] + self.stmts(st.body, depth + 1)
            if st.orelse:
                out += [ind + "} else {"] + self.stmts(st.orelse, depth + 1)
            return out + [ind + "}"]
        if t is ast.Return:
            if st.value is None:
                raise Unsupported("bare return")
            if isinstance(st.value, ast.Constant) and isinstance(st.value.value, int) \
                    and not isinstance(st.value.value, bool):
                self.ret_kinds.add("int64")
                val = str(st.value.value)
            else:
                self.ret_kinds.add("double")
                val = self.expr(st.value)
            return [f"{ind}return {val};"]   # (the last statement: translate() adds the frees)
        raise Unsupported(f"statement {t.__name__}")

    def _loop_bound(self, node) -> str:
        try:
            return str(self.int_const(node))
        except Unsupported:
            self._check_int(node)
            return self.expr(node, index=True)

    def translate(self) -> CKernel:
        k = self._translate()
        k.stores_2d = sum(1 for n in ast.walk(self.fn) if isinstance(n, (ast.Assign, ast.AugAssign))
                          for t in (n.targets if isinstance(n, ast.Assign) else [n.target])
                          if isinstance(t, ast.Subscript) and isinstance(t.slice, ast.Tuple))
        return k

    def _translate(self) -> CKernel:
        fn = self.fn
        doc = ast.get_docstring(fn) or ""
        body = [st for st in fn.body if not (isinstance(st, ast.Expr) and isinstance(st.value, ast.Constant))]
        if not body or not isinstance(body[-1], ast.Return):
            raise Unsupported("a kernel that does not end in a return")
        if any(isinstance(n, ast.Return) for st in body[:-1] for n in ast.walk(st)):
            raise Unsupported("a return before the end")
        items = []   # (C lines, names defined, names used, local array declaration?)
        for st in body[:-1]:
            c = self.stmt(st, 1)
            defs = {n.id for n in ast.walk(st) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store)}
            uses = {n.id for n in ast.walk(st) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)}
            if isinstance(st, ast.AugAssign) and isinstance(st.target, ast.Name):
                uses.add(st.target.id)
            is_array = (isinstance(st, ast.Assign) and isinstance(st.targets[0], ast.Name)
                        and st.targets[0].id in self.f.arrays)
            items.append((c, defs, uses, is_array))
        ret_line = self.stmt(body[-1], 1)[0]
        ret = self.ret_kinds.pop()
        if self.ret_kinds:
            raise Unsupported("returns both integers and values")
        ctype = "double" if ret == "double" else "int64_t"
        params, pnames = [], []
        for a, k in self.f.args.items():
            if k == "-":
                continue
            if k == "s":
                params.append(f"double {self.cid(a)}")
                pnames.append(self.cid(a))
            elif k == "1":
                params.append(f"double *restrict {self.cid(a)}")
                pnames.append(self.cid(a))
            else:
                params.append(f"double *restrict {self.cid(a)}, int64_t r_{self.cid(a)}")
                pnames += [self.cid(a), "r_" + self.cid(a)]
        n_lines = sum(len(c) for c, _, _, _ in items)
        sig = f"{ctype} __NAME__({', '.join(params)})"
        if n_lines <= 2 * SEGMENT_LINES:
            lines = [ln for c, _, _, _ in items for ln in c]
            decl = self._decls(list(self.f.scalars), list(self.f.loopvars))
            frees = "".join(f" free({h});" for h in self.f.heap)
            tail = [f"    {{ {ctype} _r = {ret_line.strip()[len('return '):-1]};{frees} return _r; }}"] if frees \
                else [ret_line]
            text = "\n".join(decl + lines + tail)
            return CKernel(fn.name, list(self.f.args.items()), ret, sig + " {\n" + text + "\n}\n", doc,
                           statements=n_lines)
        return self._segmented(fn, doc, items, ret_line, ret, ctype, sig, params, pnames, n_lines)

    @staticmethod
    def _decls(scalars, loopvars, indent="    "):
        out = []
        for i in range(0, len(scalars), 16):
            out.append(indent + "double " + ", ".join("p_" + n for n in scalars[i:i + 16]) + ";")
        if loopvars:
            out.append(indent + "int64_t " + ", ".join("p_" + n for n in loopvars) + ";")
        return out

    def _segmented(self, fn, doc, items, ret_line, ret, ctype, sig, params, pnames, n_lines) -> CKernel:
        """A long kernel as a chain of functions of ~SEGMENT_LINES statements each (noinline): a value
        crossing a boundary lives in a frame array F, the others stay locals of their segment. The
        C compiler's register allocator is superlinear in the live values of one function; this keeps
        each function small (the same operations in the same order: the numbers do not change)."""
        for st in fn.body:  # a loop variable read after its loop would cross segments uninitialised
            if not isinstance(st, ast.For):
                if any(isinstance(n, ast.Name) and n.id in self.f.loopvars for n in ast.walk(st)):
                    raise Unsupported("a loop variable used outside its loop")
        arrays = [(c, d) for c, d, _, is_arr in items if is_arr]
        stmts = [(c, d, u) for c, d, u, is_arr in items if not is_arr]
        segs, cur, size = [], [], 0
        for it in stmts:
            cur.append(it)
            size += len(it[0])
            if size >= SEGMENT_LINES:
                segs.append(cur)
                cur, size = [], 0
        if cur or not segs:
            segs.append(cur)
        ret_uses = {n.id for n in ast.walk(fn.body[-1]) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)}
        where: dict = {}
        for k, seg in enumerate(segs):
            for _, d, u in seg:
                for v in d | u:
                    where.setdefault(v, set()).add(k)
        for v in ret_uses:
            where.setdefault(v, set()).add(len(segs) - 1)
        scalars = [v for v in self.f.scalars]
        frame = {v: i for i, v in enumerate(v for v in scalars if len(where.get(v, ())) > 1)}
        local_arrays = [self.cid(a) for a in self.f.arrays]
        rx = re.compile(r"\bp_(\w+)\b")

        def sub(line):
            return rx.sub(lambda m: f"F[{frame[m.group(1)]}]" if m.group(1) in frame else m.group(0), line)

        seg_params = ", ".join(["double *restrict F"] + params + [f"double *restrict {a}" for a in local_arrays])
        seg_args = ", ".join(["F"] + pnames + local_arrays)
        out = []
        for k, seg in enumerate(segs):
            last = k == len(segs) - 1
            used = set().union(*[d | u for _, d, u in seg]) if seg else set()
            if last:
                used |= ret_uses
            own = [v for v in scalars if v in used and v not in frame]
            loops = [v for v in self.f.loopvars if v in used]
            body = self._decls(own, loops) + [sub(ln) for c, _, _ in seg for ln in c]
            if last:
                body.append(sub(ret_line))
            rt = ctype if last else "void"
            out.append(f"static __attribute__((noinline)) {rt} __NAME___s{k}({seg_params}) {{\n" + "\n".join(body) + "\n}\n")
        main = []
        nf = max(1, len(frame))
        if nf > _HEAP:
            main += [f"    double *F = (double *)malloc(sizeof(double) * {nf});", "    if (!F) abort();"]
            heap = self.f.heap + ["F"]
        else:
            main.append(f"    double F[{nf}];")
            heap = list(self.f.heap)
        for c, _ in arrays:
            main += c
        for k in range(len(segs) - 1):
            main.append(f"    __NAME___s{k}({seg_args});")
        main.append(f"    {ctype} _r = __NAME___s{len(segs) - 1}({seg_args});")
        main += [f"    free({h});" for h in heap]
        main.append("    return _r;")
        text = "\n".join(out) + "\n" + sig + " {\n" + "\n".join(main) + "\n}\n"
        return CKernel(fn.name, list(self.f.args.items()), ret, text, doc, statements=n_lines)
