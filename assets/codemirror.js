// The reward-function editor: CodeMirror 6 with Python highlighting and lint markers.
// Bundled by esbuild into static/vendor/codemirror.bundle.js (manage.py build_assets).
import { EditorView, basicSetup } from "codemirror";
import { EditorState } from "@codemirror/state";
import { python } from "@codemirror/lang-python";
import { oneDark } from "@codemirror/theme-one-dark";
import { lintGutter, setDiagnostics } from "@codemirror/lint";

// Mount an editor in `parent`, mirroring its text into `textarea` (which the form submits).
export function mount(parent, textarea, { readOnly = false } = {}) {
  const extensions = [
    basicSetup,
    python(),
    oneDark,
    lintGutter(),
    EditorView.lineWrapping,
    EditorView.updateListener.of((update) => {
      if (update.docChanged && textarea) textarea.value = update.state.doc.toString();
    }),
  ];
  if (readOnly) extensions.push(EditorState.readOnly.of(true), EditorView.editable.of(false));
  const view = new EditorView({
    state: EditorState.create({ doc: textarea ? textarea.value : "", extensions }),
    parent,
  });
  return view;
}

export function setText(view, text) {
  view.dispatch({ changes: { from: 0, to: view.state.doc.length, insert: text } });
}

// errors: [{message, lineNumber, column}] -> diagnostics on their lines (gutter + underline).
export function markErrors(view, errors) {
  const doc = view.state.doc;
  const diagnostics = errors.map((e) => {
    const lineNo = Math.min(Math.max(e.lineNumber || e.line || 1, 1), doc.lines);
    const line = doc.line(lineNo);
    return { from: line.from, to: Math.max(line.to, line.from), severity: "error", message: e.message };
  });
  view.dispatch(setDiagnostics(view.state, diagnostics));
}

export function clearErrors(view) {
  view.dispatch(setDiagnostics(view.state, []));
}
