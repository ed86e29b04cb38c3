// Lichtblick's own web build config (web/webpack.config.ts), for a local build only: the app
// bundle without its development server, its type check (ForkTsChecker: minutes and GBs on
// top) and its source maps. tests/viewer/setup_lichtblick.sh copies this file into web/.
import type { Configuration } from "webpack";

import configs from "./webpack.config";

type ConfigFn = (env: unknown, argv: { mode?: string }) => Configuration;

const main = configs[1] as unknown as ConfigFn;

export default (env: unknown, argv: { mode?: string }): Configuration => {
  const config = main(env, argv);
  config.plugins = (config.plugins ?? []).filter(
    (p) => p?.constructor.name !== "ForkTsCheckerWebpackPlugin",
  );
  config.devtool = false;
  return config;
};
