// Validate a .glb with the Khronos glTF validator; print the report's issues as JSON.
// Usage: node validate.js FILE.glb
const fs = require('fs');
const validator = require('gltf-validator');
const data = new Uint8Array(fs.readFileSync(process.argv[2]));
validator.validateBytes(data, { maxIssues: 100 })
  .then((report) => { console.log(JSON.stringify(report.issues)); })
  .catch((err) => { console.error(String(err)); process.exit(1); });
