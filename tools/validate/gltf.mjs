// Runs the Khronos glTF-Validator (npm package `gltf-validator`) on one .glb or .gltf file.
//
// Usage: node tools/validate/gltf.mjs FILE
// Prints one JSON line {"file", "errors", "warnings", "infos", "hints", "messages", "info"} to stdout
// and exits 0 when the validator reports no errors, 1 when it reports errors, 2 when it could not
// run (missing file, unreadable asset). External resources (the .bin of a .gltf) are loaded from
// the file's directory, so a missing or short .bin is an error.
import { readFile } from "node:fs/promises";
import path from "node:path";
import { createRequire } from "node:module";

const require = createRequire(import.meta.url);
const validator = require("gltf-validator");

const file = process.argv[2];
if (!file) {
  console.error("usage: node gltf.mjs FILE.glb|FILE.gltf");
  process.exit(2);
}

try {
  const bytes = new Uint8Array(await readFile(file));
  const report = await validator.validateBytes(bytes, {
    uri: path.basename(file),
    maxIssues: 0,
    writeTimestamp: false,
    externalResourceFunction: async (uri) =>
      new Uint8Array(await readFile(path.resolve(path.dirname(file), decodeURIComponent(uri)))),
  });
  const issues = report.issues;
  const summary = {
    file,
    validator: validator.version(),
    errors: issues.numErrors,
    warnings: issues.numWarnings,
    infos: issues.numInfos,
    hints: issues.numHints,
    messages: issues.messages.map((m) => `${m.severity} ${m.code} ${m.pointer ?? ""}: ${m.message}`),
    info: report.info,
  };
  console.log(JSON.stringify(summary));
  process.exit(issues.numErrors === 0 ? 0 : 1);
} catch (err) {
  console.error(`gltf-validator could not run on ${file}: ${err}`);
  process.exit(2);
}
