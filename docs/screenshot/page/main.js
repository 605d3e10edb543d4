// Foxglove Studio (the @foxglove/studio-base bundle) with the trial and layout named in the URL:
// index.html?ds=remote-file&ds.url=<trial.mcap>&layoutId=tumblebot
(async () => {
  const fox = window;
  await fox.initI18n();
  const data = await (await fetch("layout.json")).json();
  const layouts = new Map([["tumblebot", {
    id: "tumblebot", name: "tumblebot", permission: "CREATOR_WRITE",
    baseline: { data, savedAt: undefined }, working: undefined, syncInfo: undefined,
  }]]);
  const layoutStorage = {
    list: async () => [...layouts.values()],
    get: async (_ns, id) => layouts.get(id),
    put: async (_ns, layout) => { layouts.set(layout.id, layout); return layout; },
    delete: async (_ns, id) => { layouts.delete(id); },
    importLayouts: async () => {},
  };
  const settings = new Map(), listeners = new Map();
  const appConfiguration = {
    get: (key) => settings.get(key),
    set: async (key, value) => { settings.set(key, value); (listeners.get(key) ?? []).forEach((cb) => cb(value)); },
    addChangeListener: (key, cb) => listeners.set(key, [...(listeners.get(key) ?? []), cb]),
    removeChangeListener: (key, cb) => listeners.set(key, (listeners.get(key) ?? []).filter((f) => f !== cb)),
  };
  ReactDOM.render(React.createElement(fox.App, {
    deepLinks: [window.location.href],
    dataSources: [new fox.RemoteDataSourceFactory(), new fox.McapLocalDataSourceFactory(),
                  new fox.FoxgloveWebSocketDataSourceFactory()],
    appConfiguration, layoutStorage, extensionLoaders: [], enableGlobalCss: true,
  }), document.getElementById("root"));
})();
