// Runs the Khronos glTF validator (npm `gltf-validator`) on a .glb and prints its report's
// issue counts and messages as JSON; exits 1 when it reports an error.
// Usage: NODE_PATH=<dir with node_modules> node scripts/glb/validate.cjs FILE.glb
const fs = require("fs");
const validator = require("gltf-validator");

const file = process.argv[2];
validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)), { maxIssues: 50 })
  .then((report) => {
    const { numErrors, numWarnings, numInfos, messages } = report.issues;
    console.log(JSON.stringify({ numErrors, numWarnings, numInfos, messages }, null, 1));
    process.exit(numErrors === 0 ? 0 : 1);
  })
  .catch((e) => {
    console.error(`${file}: ${e}`);
    process.exit(1);
  });
